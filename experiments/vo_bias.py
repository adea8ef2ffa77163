"""The SLAM's visual edges against a simulated pass's truth: do they measure motion long or
short, and which points make them so (`bench/vo_bias.py` runs it).

* `edge_pairs`: frames of a pass `step_m` apart (translation, ground truth), spread over it.
* `edge_errors`: for one pair, the front end's own edge (`FrontEnd._relative`: guided matches
  with the true motion as the prediction, PnP, the joint refinement with both depths) over all
  matched points, over the floor's only (height < `FLOOR_M` in the world) and over the rest;
  each as its error along the true motion (metres, + = measured long).
* `depth_disagreement`: the same matched feature lifted with its depth in each frame, the nearer
  frame's point moved into the farther frame with the true motion: how much nearer (-) or farther
  (+) it lands along the farther camera's axis. Zero for exact keypoints; a keypoint that sits a
  little toward the far side of a foreshortened blob (more so the farther the blob) reads deeper
  in the farther frame, and the 3D terms of the refinement turn that into a longer motion.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from litevloc.base.geometry import transform_points
from litevloc.pipelines.guided_matching import match_by_projection
from litevloc.pipelines.slam.frontend import FrontEnd
from litevloc.pipelines.slam.types import FrameImages, Keyframe

F64 = NDArray[np.float64]
FLOOR_M = 0.03  # a point this close to the world's floor (z = 0) is a floor point
OFF_FLOOR_M = 0.10  # ... and one this far above it is not
SUBSETS = ("all", "floor", "off-floor")


@dataclass(frozen=True)
class FramePoints:
    """One rendered frame as the front end sees it: its keyframe record (features, lifted points)
    and the world height of each lifted point (NaN without depth)."""

    keyframe: Keyframe
    height_m: F64


def edge_pairs(T_world_camera: F64, step_m: float, count: int, max_gap: int = 150) -> list[tuple[int, int]]:
    """Up to `count` (i, j) frame pairs spread over a pass (`T_world_camera` (F, 4, 4)): j the
    first frame at least `step_m` from i, within `max_gap` frames (a robot that stood still)."""
    pos = T_world_camera[:, :3, 3]
    out: list[tuple[int, int]] = []
    for i in np.linspace(0, max(len(pos) - max_gap - 1, 0), 2 * count).astype(int):
        d = np.linalg.norm(pos[i + 1: i + 1 + max_gap] - pos[i], axis=1)
        far = np.nonzero(d >= step_m)[0]
        if len(far):
            out.append((int(i), int(i + 1 + far[0])))
        if len(out) == count:
            break
    return out


def frame_points(fe: FrontEnd, images: FrameImages, K: F64, T_world_camera: F64, index: int) -> FramePoints:
    """The front end's features of a frame, as a keyframe record, with its points' world heights."""
    feats, pts = fe._features(images, K)  # the front end's own extraction and lifting, not a copy
    h, w = images.color.shape[:2]
    kf = Keyframe(id=index, index=index, t_ns=0, K=np.asarray(K, np.float64), size=(w, h), features=feats,
                  points=pts, vpr=np.zeros(1, np.float32), jpeg=b"", cloud=np.zeros((0, 3), np.float32), odom=None,
                  T_init=np.eye(4), chain=0, view=fe._view(images, K))
    return FramePoints(kf, transform_points(T_world_camera, pts)[:, 2])


def subset_mask(height_m: F64, subset: str) -> NDArray[np.bool_]:
    """Which lifted points (by world height, metres) belong to `subset` (see `SUBSETS`)."""
    if subset == "all":
        return np.isfinite(height_m)
    if subset == "floor":
        return np.abs(height_m) < FLOOR_M
    if subset == "off-floor":
        return height_m > OFF_FLOOR_M
    raise ValueError(f"unknown subset {subset!r}; one of {SUBSETS}")


def along_motion_error(T_est: F64, T_true: F64) -> float:
    """Error of a measured motion along the true one (metres; + = measured long)."""
    t = T_true[:3, 3]
    return float((T_est[:3, 3] - t) @ t / np.linalg.norm(t))


def edge_errors(fe: FrontEnd, target: FramePoints, source: FramePoints, T_target_source: F64) -> dict[str, float]:
    """Along-motion error (metres) of the front end's edge from `source` to `target` per subset
    (NaN where its gates refuse); the true motion is the matching's prediction."""
    out: dict[str, float] = {}
    for subset in SUBSETS:
        pts = source.keyframe.points.copy()
        pts[~subset_mask(source.height_m, subset)] = np.nan  # the edge uses lifted points only
        res = fe._relative(pts, source.keyframe.features, target.keyframe, T_target_source, True,
                           source.keyframe.view)
        out[subset] = float("nan") if res is None else along_motion_error(res.T, T_target_source)
    return out


def depth_disagreement(fe: FrontEnd, far: FramePoints, near: FramePoints, T_far_near: F64) -> F64:
    """(M, 3): per matched feature with depth in both frames: its depth in the farther frame
    (metres), how much nearer (-) or farther (+) the nearer frame's point lands there along the
    camera axis (metres), and its world height (metres)."""
    vp = fe.params.visual
    i_s, i_t = match_by_projection(near.keyframe.points, near.keyframe.features.descriptors, T_far_near,
                                   far.keyframe.features.keypoints, far.keyframe.features.descriptors,
                                   far.keyframe.K, np.eye(4), vp.guided_radius_px, vp.guided_min_similarity, True)
    a = transform_points(T_far_near, near.keyframe.points[i_s])
    b = far.keyframe.points[i_t]
    ok = np.all(np.isfinite(a), axis=1) & np.all(np.isfinite(b), axis=1)
    return np.column_stack([b[ok, 2], a[ok, 2] - b[ok, 2], near.height_m[i_s][ok]])


def summary(errors: list[dict[str, float]], steps: list[float], disagreement: F64,
            gross_m: float = 0.05) -> dict[str, Any]:
    """Medians over the pairs and the error per metre (their sum over the steps': what a chain
    of edges accumulates), gross errors (> `gross_m`: a texture repeating about one step along
    the path) counted apart; the depth disagreement by surface and range."""
    out: dict[str, Any] = {"pairs": len(errors), "step_median_m": float(np.median(steps)) if steps else None}
    st = np.asarray(steps, np.float64)
    for subset in SUBSETS:
        e = np.asarray([x[subset] for x in errors], np.float64)
        ok = np.isfinite(e) & (np.abs(e) <= gross_m)
        out[subset] = {"edges": int(np.isfinite(e).sum()), "gross": int((np.abs(e) > gross_m).sum()),
                       "along_error_median_mm": float(1e3 * np.median(e[ok])) if ok.any() else None,
                       "along_error_median_pct": float(100 * np.median(e[ok] / st[ok])) if ok.any() else None,
                       # what a chain of edges adds up: the error per metre travelled over the pairs
                       "along_error_per_m_pct": float(100 * e[ok].sum() / st[ok].sum()) if ok.any() else None}
    rows = []
    for subset in ("floor", "off-floor"):
        m = subset_mask(disagreement[:, 2], subset) & (np.abs(disagreement[:, 1]) < 0.2)
        for lo, hi in ((0.0, 2.0), (2.0, 4.0), (4.0, 10.0)):
            mm = m & (disagreement[:, 0] >= lo) & (disagreement[:, 0] < hi)
            if mm.sum() >= 20:
                d = disagreement[mm]
                rows.append({"surface": subset, "range_m": [lo, hi], "features": int(mm.sum()),
                             "median_mm": float(1e3 * np.median(d[:, 1])),
                             "median_pct": float(100 * np.median(d[:, 1] / d[:, 0]))})
    out["depth_disagreement"] = rows
    return out

