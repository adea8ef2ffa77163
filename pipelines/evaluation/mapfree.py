"""The map-free relocalization benchmark's metrics, implemented from its published definitions.

Niantic's map-free benchmark (Arnold et al., ECCV 2022; the scorer `benchmark/mapfree.py` of
nianticlabs/map-free-reloc) scores, per *scene* (one reference image, many queries), each
query's estimated pose against the ground truth, both as world-to-camera transforms whose
world frame is the reference image's camera frame:

- translation error: distance (m) between the estimated and true camera centres;
- rotation error: the angle (deg) of `q_est * q_gt^-1`, computed from its sine
  (`2 asin(|vector part|)`, so it saturates at 180 deg as the scorer's does);
- VCRE, the virtual correspondence reprojection error (px): a fixed grid of 7 x 4 x 7 virtual
  points 0.3 m apart in front of the query camera (x, y centred on the optical axis, z from
  1.8 m to 3.6 m) is projected with the true pose and with the estimated one (the estimate's
  residual transform `inv(cam2world_est) @ cam2world_gt` applied to the points), both
  projections clamped to the image borders; the error is the mean pixel distance.

Aggregates (over all scenes; a query without an estimate is a *failure* and counts in every
denominator): average over scenes of the median of each error, precision at
pose error < (25 cm, 5 deg) and at VCRE < 90 px, and the AUC of the precision-recall curve
obtained by sweeping a threshold over the estimates' confidence, and the share of queries
with an estimate. The official val/test protocol also keeps only every 5th ground-truth
frame of a scene (`subsample`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from litevloc.base.geometry import invert, so3_log

T_THRESHOLD_M = 0.25
R_THRESHOLD_DEG = 5.0
VCRE_THRESHOLD_PX = 90.0


def virtual_points() -> NDArray[np.float64]:
    """(196, 3) VCRE grid in the query camera frame (metres, x right, y down, z forward)."""
    step = 0.3
    x = (np.arange(7) - 3.0) * step
    y = (np.arange(4) - 1.5) * step
    z = 1.8 + np.arange(7) * step
    xx, yy, zz = np.meshgrid(x, y, z)
    return np.stack([xx.ravel(), yy.ravel(), zz.ravel()], axis=1)


_GRID = virtual_points()


def _project_clamped(p: NDArray[np.float64], K: NDArray[np.float64], W: float, H: float) -> NDArray[np.float64]:
    uvw = p @ np.asarray(K, dtype=np.float64).T
    uv = uvw[:, :2] / uvw[:, 2:3]
    return np.stack([np.clip(uv[:, 0], 0, W), np.clip(uv[:, 1], 0, H)], axis=1)


def vcre_px(T_cam_world_est: NDArray[np.floating], T_cam_world_gt: NDArray[np.floating],
            K: NDArray[np.floating], W: float, H: float) -> float:
    """Mean virtual-correspondence reprojection error (px) of one estimate (4x4 world-to-camera
    poses; `K` 3x3 and the image size W x H of the query camera)."""
    K64 = np.asarray(K, dtype=np.float64)
    residual = np.asarray(T_cam_world_est, dtype=np.float64) @ invert(T_cam_world_gt)  # cam_gt -> cam_est
    moved = _GRID @ residual[:3, :3].T + residual[:3, 3]
    diff = _project_clamped(_GRID, K64, W, H) - _project_clamped(moved, K64, W, H)
    err = np.linalg.norm(diff, axis=1)
    return float(err.mean())


def pose_errors(T_cam_world_est: NDArray[np.floating], T_cam_world_gt: NDArray[np.floating]) -> tuple[float, float]:
    """(translation error m between camera centres, rotation error deg) as the scorer defines them."""
    c_est = invert(T_cam_world_est)
    c_gt = invert(T_cam_world_gt)
    dt = float(np.linalg.norm(c_est[:3, 3] - c_gt[:3, 3]))
    # the scorer compares cam2world quaternions: q_est * q_gt^-1  <->  R_est @ R_gt^T
    R = c_est[:3, :3] @ c_gt[:3, :3].T
    # its 2 asin(|vector part of the quaternion|) is the rotation angle, in [0, 180] deg
    return dt, float(np.degrees(np.linalg.norm(so3_log(R))))


def precision_recall_auc(confidence: NDArray[np.floating], tp: NDArray[np.bool_], failures: int) -> float:
    """Area under the precision-recall curve of estimates ranked by confidence (the scorer's
    `precision_recall`): each distinct confidence is a threshold; recall counts failures in
    its denominator; the curve is closed at (recall 0, precision 1)."""
    conf = np.asarray(confidence, dtype=np.float64).reshape(-1)
    hit = np.asarray(tp, dtype=bool).reshape(-1)
    if len(conf) != len(hit):
        raise ValueError("confidence and tp must have the same length")
    if len(conf) == 0:
        return 0.0
    order = np.argsort(conf, kind="stable")[::-1]
    conf, hit = conf[order], hit[order]
    cut = np.r_[np.flatnonzero(np.diff(conf)), len(conf) - 1]  # last index of each confidence level
    ranks = np.arange(1, len(conf) + 1, dtype=np.float64)
    prec = np.cumsum(hit)[cut] / ranks[cut]
    rec = ranks[cut] / (len(conf) + failures)
    prec = np.r_[prec[::-1], 1.0]
    rec = np.r_[rec[::-1], 0.0]
    return float(abs(np.sum(np.diff(rec) * prec[:-1])))


@dataclass(frozen=True)
class QueryScore:
    """One scored estimate (an estimate-less query is a failure instead)."""

    trans_err_m: float
    rot_err_deg: float
    vcre_px: float
    confidence: float


def score_query(T_cam_world_est: NDArray[np.floating], T_cam_world_gt: NDArray[np.floating],
                K: NDArray[np.floating], W: float, H: float, confidence: float) -> QueryScore:
    dt, dr = pose_errors(T_cam_world_est, T_cam_world_gt)
    return QueryScore(dt, dr, vcre_px(T_cam_world_est, T_cam_world_gt, K, W, H), float(confidence))


def mapfree_metrics(scenes: dict[str, list[QueryScore]], failures: int,
                    t_threshold_m: float = T_THRESHOLD_M, r_threshold_deg: float = R_THRESHOLD_DEG,
                    vcre_threshold_px: float = VCRE_THRESHOLD_PX) -> dict[str, float]:
    """The scorer's output dictionary (same keys) from the per-scene scores and the number of
    queries without an estimate."""
    scored = [s for v in scenes.values() for s in v]
    total = len(scored) + failures
    if not scored:
        raise ValueError("no estimate to score")
    t = np.array([s.trans_err_m for s in scored])
    r = np.array([s.rot_err_deg for s in scored])
    v = np.array([s.vcre_px for s in scored])
    c = np.array([s.confidence for s in scored])
    med = {k: float(np.mean([np.median([getattr(s, k) for s in ss]) for ss in scenes.values() if ss]))
           for k in ("trans_err_m", "rot_err_deg", "vcre_px")}
    ok_pose = (t < t_threshold_m) & (r < r_threshold_deg)
    ok_vcre = v < vcre_threshold_px
    pose_name = f"({t_threshold_m * 100}cm, {r_threshold_deg:g}deg)"
    return {
        "Average Median Translation Error": med["trans_err_m"],
        "Average Median Rotation Error": med["rot_err_deg"],
        "Average Median Reprojection Error": med["vcre_px"],
        f"Precision @ Pose Error < {pose_name}": float(ok_pose.sum() / total),
        f"AUC @ Pose Error < {pose_name}": precision_recall_auc(c, ok_pose, failures),
        f"Precision @ VCRE < {vcre_threshold_px:g}px": float(ok_vcre.sum() / total),
        f"AUC @ VCRE < {vcre_threshold_px:g}px": precision_recall_auc(c, ok_vcre, failures),
        "Estimates for % of frames": len(scored) / total,
    }
