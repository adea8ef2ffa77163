"""Errors of a SLAM result against a reference trajectory (ground truth), read only after the build.

* keyframe ATE: RMSE of the keyframe camera positions after an SE(3) Umeyama alignment (no
  scale) onto the reference (`pipelines.evaluation.trajectory`);
* RPE per metre: relative translation error over >= 1 m of reference path, RMSE (m/m);
* odometry-only ATE: the recording's odometry (chained, camera frame) at the same keyframes;
* no-loop ATE: the graph optimised without its loop edges (what the loops bought);
* wrong loops: loop edges whose relative pose differs from the reference's by more than
  0.3 m or 5 deg, and how many of them the optimiser kept.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from litevloc.base.geometry import invert, relative_pose_error
from litevloc.pipelines.evaluation.trajectory import TrajectoryError, ate, rpe_per_metre, umeyama_se3
from litevloc.pipelines.slam.types import F64, Edge

WRONG_LOOP_M = 0.3
WRONG_LOOP_DEG = 5.0


def align_se3(est: F64, ref: F64) -> F64:
    """4x4 T_ref_est aligning estimated camera positions (N, 4, 4) onto the reference's (no scale)."""
    return umeyama_se3(np.asarray(est)[:, :3, 3], np.asarray(ref)[:, :3, 3])


def loop_errors(loops: list[Edge], ref_by_id: dict[int, F64]) -> list[tuple[float, float] | None]:
    """Per loop edge, (metres, degrees) between its `T_a_b` and the reference's relative pose
    (None where a reference pose is missing)."""
    out: list[tuple[float, float] | None] = []
    for e in loops:
        if e.a not in ref_by_id or e.b not in ref_by_id:
            out.append(None)
            continue
        out.append(relative_pose_error(e.T_a_b, invert(ref_by_id[e.a]) @ ref_by_id[e.b]))
    return out


def trajectory_errors(est: F64, ref: F64) -> dict[str, float | None]:
    """ATE (RMSE, median, max; metres) and RPE per metre (RMSE) of aligned poses (N, 4, 4)."""
    if len(est) < 3:
        return {"ate_m": None, "ate_median_m": None, "ate_max_m": None, "rpe_per_m": None}
    a = ate(est, ref)
    try:
        r: float | None = rpe_per_metre(est, ref, 1.0).rmse
    except TrajectoryError:
        r = None  # a path shorter than a metre
    return {"ate_m": a.rmse, "ate_median_m": a.median, "ate_max_m": a.max, "rpe_per_m": r}


def evaluate(poses: dict[int, F64], ref_by_id: dict[int, F64], loops: list[Edge], loop_weights: list[float],
             kept_weight: float, odometry_by_id: dict[int, F64] | None = None,
             no_loop_poses: dict[int, F64] | None = None) -> dict[str, Any]:
    """The report's error block (see the module docstring); ids are keyframe ids."""
    ids = sorted(k for k in poses if k in ref_by_id)
    est = np.stack([poses[k] for k in ids]) if ids else np.zeros((0, 4, 4))
    ref = np.stack([ref_by_id[k] for k in ids]) if ids else np.zeros((0, 4, 4))
    errs = trajectory_errors(est, ref)
    out: dict[str, Any] = {"keyframes_compared": len(ids), "keyframe_ate_m": errs["ate_m"],
                           "keyframe_ate_median_m": errs["ate_median_m"], "keyframe_ate_max_m": errs["ate_max_m"],
                           "rpe_per_m": errs["rpe_per_m"]}
    if len(ids) >= 3:
        out["T_reference_map"] = align_se3(est, ref).tolist()
    for name, other in (("odometry", odometry_by_id), ("no_loop", no_loop_poses)):
        if other is None:
            out[f"{name}_ate_m"] = None
            continue
        oid = [k for k in ids if k in other]
        oe = trajectory_errors(np.stack([other[k] for k in oid]), np.stack([ref_by_id[k] for k in oid])) \
            if len(oid) >= 3 else {"ate_m": None}
        out[f"{name}_ate_m"] = oe["ate_m"]
    lerr = loop_errors(loops, ref_by_id)
    wrong = [e is not None and (e[0] > WRONG_LOOP_M or e[1] > WRONG_LOOP_DEG) for e in lerr]
    out["wrong_loops"] = int(sum(wrong))
    out["wrong_loops_kept"] = int(sum(w and lw > kept_weight for w, lw in zip(wrong, loop_weights, strict=True)))
    out["loop_error_median_m"] = float(np.median([e[0] for e in lerr if e is not None])) if any(lerr) else None
    return out
