"""The two graphs of the map.

Covisibility (CvG, for localization): for keyframe pairs closer than `max_distance_m`
whose optical axes differ by less than `max_angle_deg` (pairs from a KD-tree), match the
cached features (by default guided by the two mapping poses, see `CovisibilityParams.matching`),
lift node i's matched keypoints with its depth and solve PnP into node j (RANSAC, seeded).
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

from collections.abc import Callable, Sequence

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from litevloc.base.geometry import backproject_pixels
from litevloc.base.params.mapping import ConnectivityParams, CovisibilityParams
from litevloc.pipelines.guided_matching import match_by_projection
from litevloc.pipelines.pnp import solve_pnp
from litevloc.pipelines.topomap.occupancy import segment_is_free
from litevloc.pipelines.topomap.types import FeatureSet, OccupancyGrid

MatchFn = Callable[[FeatureSet, FeatureSet], tuple[NDArray[np.int64], NDArray[np.int64]]]


def covisibility_candidates(T_map_camera: NDArray[np.float64], params: CovisibilityParams) -> list[tuple[int, int]]:
    """Pairs (i < j), sorted, passing the distance and viewing-angle gates (T_map_camera (N, 4, 4))."""
    T = np.asarray(T_map_camera, dtype=np.float64).reshape(-1, 4, 4)
    if len(T) < 2:
        return []
    pos, z = T[:, :3, 3], T[:, :3, 2]
    pairs = cKDTree(pos).query_pairs(params.max_distance_m, output_type="ndarray")
    if len(pairs) == 0:
        return []
    pairs = np.sort(pairs, axis=1)
    cos = np.einsum("ij,ij->i", z[pairs[:, 0]], z[pairs[:, 1]])
    pairs = pairs[cos >= np.cos(np.radians(params.max_angle_deg))]
    pairs = pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]
    return [(int(i), int(j)) for i, j in pairs]


def lift_keypoints(K: NDArray[np.float64], keypoints: NDArray[np.floating],
                   depth: NDArray[np.floating]) -> NDArray[np.float64]:
    """(N, 3) camera-frame points of N keypoints (pixels) lifted with their depth (N,) metres;
    NaN rows where the depth is missing (NaN or <= 0)."""
    z = np.asarray(depth, dtype=np.float64)
    pts = np.full((len(z), 3), np.nan)
    ok = np.isfinite(z) & (z > 0)
    if ok.any():
        pts[ok] = backproject_pixels(K, np.asarray(keypoints, dtype=np.float64).reshape(-1, 2)[ok], z[ok])
    return pts


def guided_pair_matches(
    f_i: FeatureSet, depth_i: NDArray[np.float32], K_i: NDArray[np.float64], T_i: NDArray[np.float64],
    f_j: FeatureSet, K_j: NDArray[np.float64], T_j: NDArray[np.float64], params: CovisibilityParams,
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Matches (indices into i's and j's keypoints) of node i's depth-lifted keypoints
    (`depth_i` (N,) metres per keypoint, NaN = none) projected into node j with the mapping
    poses `T_i`, `T_j` (T_map_camera)."""
    pts = lift_keypoints(K_i, f_i.keypoints, depth_i)
    return match_by_projection(pts, f_i.descriptors, T_i, f_j.keypoints, f_j.descriptors, K_j, T_j,
                               params.guided_radius_px, params.guided_min_similarity, params.guided_global_mutual)


def pnp_inliers(
    f_i: FeatureSet, depth_i: NDArray[np.float32], K_i: NDArray[np.float64], f_j: FeatureSet, K_j: NDArray[np.float64],
    i0: NDArray[np.int64], i1: NDArray[np.int64], params: CovisibilityParams,
) -> int:
    """PnP inliers of the matched pairs (i0 into node i, lifted with `depth_i`; i1 into node j)."""
    if len(i0) < 4:
        return 0
    z = depth_i[i0]
    ok = np.isfinite(z)
    if ok.sum() < 4:
        return 0
    pts = backproject_pixels(K_i, f_i.keypoints[i0[ok]].astype(np.float64), z[ok].astype(np.float64))
    res = solve_pnp(pts, f_j.keypoints[i1[ok]], K_j, params.pnp)
    return res.n_inliers if res.T_target_source is not None else 0


def pair_inliers(
    f_i: FeatureSet, depth_i: NDArray[np.float32], K_i: NDArray[np.float64], T_i: NDArray[np.float64],
    f_j: FeatureSet, K_j: NDArray[np.float64], T_j: NDArray[np.float64], match: MatchFn, params: CovisibilityParams,
) -> int:
    """A covisibility candidate pair's PnP inliers (node i lifted with `depth_i` into node j),
    with matches guided by the mapping poses `T_i`, `T_j` or from `match`, as
    `params.matching` says."""
    if params.matching == "guided":
        i0, i1 = guided_pair_matches(f_i, depth_i, K_i, T_i, f_j, K_j, T_j, params)
    else:
        i0, i1 = match(f_i, f_j)
    return pnp_inliers(f_i, depth_i, K_i, f_j, K_j, i0, i1, params)


def build_covisibility(
    T_map_camera: NDArray[np.float64], K: NDArray[np.float64], features: Sequence[FeatureSet],
    keypoint_depth: Sequence[NDArray[np.float32]], match: MatchFn, params: CovisibilityParams,
    on_pair: Callable[[], None] | None = None,
) -> tuple[NDArray[np.int64], NDArray[np.int32], NDArray[np.float32]]:
    """(E,2) edges, (E,) inliers, (E,) weights of the covisibility graph."""
    edges, inl = [], []
    for i, j in covisibility_candidates(T_map_camera, params):
        n = pair_inliers(features[i], keypoint_depth[i], K[i], T_map_camera[i], features[j], K[j], T_map_camera[j],
                         match, params)
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
