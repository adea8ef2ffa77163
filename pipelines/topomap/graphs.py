"""The two graphs of the map.

Covisibility (CvG, for localization): for keyframe pairs closer than `max_distance_m`
whose optical axes differ by less than `max_angle_deg`, match the cached features, lift
node i's matched keypoints with its depth and solve PnP into node j (RANSAC, seeded).
An edge exists if the PnP inliers reach `min_inliers`; weight = min(inliers /
`weight_saturation`, 1).

Connectivity (CnG, for planning), the rule:
* keyframes consecutive in time are connected (the camera travelled between them),
  weighted by the path length travelled between them;
* any other pair whose ground-plane distance is at most `max_line_of_sight_m` is
  connected if the straight segment between them crosses no occupied grid cell,
  weighted by that distance — keeping, per node, only its `max_line_of_sight_neighbours`
  nearest such partners (an edge stays if either end keeps it). Dense clusters of keyframes
  would otherwise form near-complete graphs that cost storage and add no shorter paths.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from litevloc.base.params.mapping import ConnectivityParams as ConnectivityParams
from litevloc.base.params.mapping import CovisibilityParams as CovisibilityParams
from litevloc.pipelines.geometry import backproject_pixels
from litevloc.pipelines.pnp import solve_pnp
from litevloc.pipelines.topomap.occupancy import segment_is_free
from litevloc.pipelines.topomap.types import FeatureSet, OccupancyGrid

MatchFn = Callable[[FeatureSet, FeatureSet], tuple[NDArray[np.int64], NDArray[np.int64]]]


def covisibility_candidates(T_map_camera: NDArray[np.float64], params: CovisibilityParams) -> list[tuple[int, int]]:
    """Pairs (i < j) passing the distance and viewing-angle gates."""
    pos = T_map_camera[:, :3, 3]
    z = T_map_camera[:, :3, 2]
    cos_max = np.cos(np.radians(params.max_angle_deg))
    pairs = []
    for i in range(len(pos)):
        for j in range(i + 1, len(pos)):
            if np.linalg.norm(pos[i] - pos[j]) <= params.max_distance_m and float(z[i] @ z[j]) >= cos_max:
                pairs.append((i, j))
    return pairs


def verify_pair(
    f_i: FeatureSet, depth_i: NDArray[np.float32], K_i: NDArray[np.float64], f_j: FeatureSet, K_j: NDArray[np.float64],
    match: MatchFn, params: CovisibilityParams,
) -> int:
    """PnP inliers of node i's depth-lifted keypoints against node j's pixels (0 if none)."""
    i0, i1 = match(f_i, f_j)
    if len(i0) < 4:
        return 0
    z = depth_i[i0]
    ok = np.isfinite(z)
    if ok.sum() < 4:
        return 0
    pts = backproject_pixels(K_i, f_i.keypoints[i0[ok]].astype(np.float64), z[ok].astype(np.float64))
    res = solve_pnp(pts, f_j.keypoints[i1[ok]], K_j, params.pnp)
    return res.n_inliers if res.T_target_source is not None else 0


def build_covisibility(
    T_map_camera: NDArray[np.float64], K: NDArray[np.float64], features: list[FeatureSet],
    keypoint_depth: list[NDArray[np.float32]], match: MatchFn, params: CovisibilityParams,
    on_pair: Callable[[], None] | None = None,
) -> tuple[NDArray[np.int64], NDArray[np.int32], NDArray[np.float32]]:
    """(E,2) edges, (E,) inliers, (E,) weights of the covisibility graph."""
    edges, inl = [], []
    for i, j in covisibility_candidates(T_map_camera, params):
        n = verify_pair(features[i], keypoint_depth[i], K[i], features[j], K[j], match, params)
        if on_pair is not None:
            on_pair()
        if n >= params.min_inliers:
            edges.append((i, j))
            inl.append(n)
    e = np.array(edges, dtype=np.int64).reshape(-1, 2)
    n_in = np.array(inl, dtype=np.int32)
    w = np.minimum(n_in / params.weight_saturation, 1.0).astype(np.float32)
    return e, n_in, w


def build_connectivity(
    node_frame_positions: NDArray[np.intp], trajectory_map: NDArray[np.float64], grid: OccupancyGrid,
    params: ConnectivityParams,
) -> tuple[NDArray[np.int64], NDArray[np.float32]]:
    """(F,2) edges and (F,) metres of the connectivity graph.

    Args:
        node_frame_positions: (N,) index of each node into `trajectory_map`, increasing
            with node id (nodes are stored in time order).
        trajectory_map: (T, 3) camera centres of all frames of the mapping pass, in order.
    """
    pos = trajectory_map[np.asarray(node_frame_positions)]
    steps = np.linalg.norm(np.diff(trajectory_map, axis=0), axis=1)
    cum = np.concatenate([[0.0], np.cumsum(steps)])
    xy = grid.to_plane(pos)
    best: dict[tuple[int, int], float] = {}
    n = len(pos)
    for k in range(n - 1):
        a, b = node_frame_positions[k], node_frame_positions[k + 1]
        best[(k, k + 1)] = float(cum[b] - cum[a])
    partners: list[list[tuple[float, int]]] = [[] for _ in range(n)]
    for i in range(n):
        for j in range(i + 1, n):
            d = float(np.linalg.norm(xy[i] - xy[j]))
            if d <= params.max_line_of_sight_m and segment_is_free(grid, xy[i], xy[j]):
                partners[i].append((d, j))
                partners[j].append((d, i))
    for i in range(n):
        for d, j in sorted(partners[i])[: params.max_line_of_sight_neighbours]:
            key = (min(i, j), max(i, j))
            best[key] = min(best.get(key, np.inf), d)
    keys = sorted(best)
    return np.array(keys, dtype=np.int64).reshape(-1, 2), np.array([best[k] for k in keys], dtype=np.float32)
