"""Pose SLAM: fixed-lag online fusion (online.py), batch PS-Opt (batch.py), parameters
(params.py, GTSAM-free), seeded simulation (simulate.py) and the benchmark (experiment.py)."""
