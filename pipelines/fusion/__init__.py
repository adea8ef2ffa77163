"""Pose SLAM: fixed-lag online fusion (online.py) and batch PS-Opt (batch.py); parameters in
`litevloc.base.params.fusion`, the seeded simulation and the benchmark in `litevloc.experiments`."""
