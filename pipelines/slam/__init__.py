"""Pose-graph SLAM for the mapping pass: poses for `map build` from what the robot records.

Modules, one job each (arrays and injected model callables in, results out; no I/O):

* `odometry`: the robot's odometry split into trustworthy segments (gaps and jumps), and its
  noise model as pose-graph edges.
* `frontend`: keyframes on odometry motion (or on visual tracking where the odometry is
  missing), their features, depth and place descriptor, visual edges to the previous keyframes.
* `loops`: loop candidates from the place descriptors (bounded per keyframe) and their
  verification with the localizer's geometry (matcher + PnP with depth + a second view).
* `graph`: the pose graph in GTSAM, optimised with graduated non-convexity over the loops.
* `frames`: a pose for every frame from the optimised keyframes; external trajectories
  (TUM files) interpolated to frame stamps.
* `session`: the pass put together (`SlamSession`), with its report.
* `evaluate`: errors against a reference trajectory, read only after the build.
"""
