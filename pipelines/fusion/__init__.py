"""Pose SLAM: fixed-lag online fusion (online.py), batch PS-Opt (batch.py), parameters
(its parameters: `litevloc.base.params.fusion`), seeded simulation (simulate.py) and the benchmark (experiment.py)."""
