"""One PnP of the live frame against several neighbouring map keyframes at once.

A weak candidate keyframe (too few inliers of its own) is matched, with its map neighbours,
by the matcher; the matched keyframe keypoints, lifted with the map's depth into the map
frame, and their live pixels are pooled into one PnP + RANSAC (the multi-keyframe PnP of
hloc: the query against the union of the keyframes' 3D points). A live keypoint matched to
several keyframes enters once (its first keyframe's point), so inliers are distinct live
keypoints.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from litevloc.base.geometry import backproject_pixels, invert, relative_pose_error
from litevloc.base.params.localization import PnpParams
from litevloc.pipelines.localization.query import Query
from litevloc.pipelines.pnp import PnpResult, solve_pnp


def map_neighbours(T_map_camera: NDArray[np.float64], node: int, max_m: float, max_deg: float,
                   limit: int) -> list[int]:
    """Up to `limit` keyframes other than `node` within `max_m` metres and `max_deg` degrees of
    its pose (`T_map_camera` (N, 4, 4)), nearest first."""
    d = np.linalg.norm(T_map_camera[:, :3, 3] - T_map_camera[node, :3, 3], axis=1)
    near = [int(n) for n in np.argsort(d, kind="stable") if int(n) != node and d[n] <= max_m
            and relative_pose_error(T_map_camera[n], T_map_camera[node])[1] <= max_deg]
    return near[:limit]


def pooled_pnp(q: Query, nodes: Sequence[int], params: PnpParams) -> tuple[PnpResult, dict[int, int]] | None:
    """PnP of the live pixels against the map points of the matches with `nodes` (the map's
    depth at each keyframe keypoint, NaN = none). Returns the result, whose `T_target_source`
    is `T_live_map` (map frame -> live camera), and the inliers each node contributed; None
    where the map has no depth."""
    m = q.map
    obj: list[NDArray[np.float64]] = []
    img: list[NDArray[np.float64]] = []
    owner: list[NDArray[np.int64]] = []
    seen: set[int] = set()
    live_kp = np.asarray(q.feats.keypoints, np.float64).reshape(-1, 2)
    for node in nodes:
        z = m.keypoint_depth(node)
        if z is None:
            return None
        i_live, i_kf = q.matches(node)
        zk = np.asarray(z, np.float64)[i_kf]
        fresh = np.array([int(i) not in seen for i in i_live], dtype=bool)
        ok = fresh & np.isfinite(zk) & (zk > 0)
        seen.update(int(i) for i in i_live[ok])
        kp = np.asarray(m.features[node].keypoints, np.float64).reshape(-1, 2)[i_kf[ok]]
        T = m.T_map_camera[node]
        obj.append(backproject_pixels(m.K[node], kp, zk[ok]) @ T[:3, :3].T + T[:3, 3])
        img.append(live_kp[i_live[ok]])
        owner.append(np.full(int(ok.sum()), node, np.int64))
    res = solve_pnp(np.concatenate(obj), np.concatenate(img), q.K, params)
    who = np.concatenate(owner)[res.inliers]
    return res, {int(n): int(np.count_nonzero(who == n)) for n in nodes}


def as_keyframe_result(res: PnpResult, T_map_node: NDArray[np.float64]) -> PnpResult:
    """A pooled result (`T_target_source` = T_live_map) re-expressed against one keyframe:
    `T_target_source` = T_node_live, as `relative_pose` gives it (covariance dropped: the joint
    refinement gives the pose's own)."""
    assert res.T_target_source is not None
    T_node_live = invert(T_map_node) @ invert(res.T_target_source)
    return PnpResult(res.accepted, res.reason, T_node_live, res.inliers, res.n_matches, res.median_reprojection_px,
                     None, res.ransac_inliers, res.refusal)
