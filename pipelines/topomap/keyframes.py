"""Keyframe selection: motion pre-filter, then greedy coverage maximisation.

1. Pre-filter (in time order): keep a frame when it moved >= `min_translation_m` or
   turned >= `min_rotation_deg` since the last kept frame.
2. Greedy information maximisation: every candidate "covers" a set of (ground-plane
   cell, viewing-direction bin) pairs — the cells hit by its depth points (inside a
   height band), each with the direction from the camera to that cell quantised into
   `heading_bins` sectors (1 bin = the published plain 2D coverage; more bins also value
   seeing a place from a new side, which is what a query from that side needs). Each
   round picks the candidate adding the most uncovered pairs (ties: earliest frame).
   Stop when the coverage of the union reaches `coverage`, when the best gain is below
   `min_gain`, or at `budget` if one is set. The number of keyframes therefore follows
   from the coverage target and the place (a larger or more cluttered place needs more
   views); `budget` is only an explicit user cap, and callers report when it binds
   (`budget_binds`).

The greedy pass is the lazy ("accelerated") greedy of Minoux: coverage gain is
submodular, so a candidate's last computed gain is an upper bound of its current one
and only the heap top is re-evaluated. It picks exactly what the plain greedy picks
(same gains, same earliest-frame tie-break) in near-linear time in the candidates.

Streaming: `coverage_keys_sliced` turns one frame's depth points into compact keys that
keep an absolute height slice (`HEIGHT_QUANTUM_M`), so a frame can be reduced to its
keys as it arrives, before the median camera height of the whole pass (the reference
of `height_band_m`) is known; `band_keys` applies the band afterwards (the band edges
are thereby rounded to the slice centres, i.e. within HEIGHT_QUANTUM_M / 2).

No randomness: the same input and parameters always select the same keyframes.
"""

from __future__ import annotations

import heapq

import numpy as np
from numpy.typing import NDArray

from litevloc.base.geometry import backproject_pixels, rotation_angle
from litevloc.base.params.mapping import KeyframeParams

_OFF = 1 << 20
HEIGHT_QUANTUM_M = 0.1  # height slice of `coverage_keys_sliced` (m)
_SLICES = 1 << 12  # height slices per key (+-204.8 m at 0.1 m)


def moved(last: NDArray[np.float64], T: NDArray[np.float64], params: KeyframeParams) -> bool:
    """Did the camera move >= `min_translation_m` or turn >= `min_rotation_deg` from the
    4x4 pose `last` to the 4x4 pose `T` (the motion pre-filter's test)?"""
    return bool(np.linalg.norm(T[:3, 3] - last[:3, 3]) >= params.min_translation_m
                or rotation_angle(last[:3, :3].T @ T[:3, :3]) >= np.radians(params.min_rotation_deg))


def motion_prefilter(T_map_camera: NDArray[np.float64], params: KeyframeParams) -> list[int]:
    """Indices (into the (N,4,4) pose array) of frames passing the motion pre-filter."""
    if len(T_map_camera) == 0:
        return []
    kept = [0]
    for i in range(1, len(T_map_camera)):
        if moved(T_map_camera[kept[-1]], T_map_camera[i], params):
            kept.append(i)
    return kept


def plane_axes(up: NDArray[np.floating]) -> NDArray[np.float64]:
    """(2, 3) orthonormal axes spanning the plane orthogonal to `up` (right-handed with up)."""
    u = np.asarray(up, dtype=np.float64)
    u = u / np.linalg.norm(u)
    e = np.eye(3)[int(np.argmin(np.abs(u)))]
    a = np.cross(e, u)
    a /= np.linalg.norm(a)
    b = np.cross(u, a)
    return np.stack([a, b])


def coverage_keys(
    points_map: NDArray[np.float64], camera_map: NDArray[np.float64], up: NDArray[np.float64],
    ref_height: float, params: KeyframeParams,
) -> NDArray[np.int64]:
    """Unique int64 keys of the (cell, heading bin) pairs covered by one frame.

    Args:
        points_map: (N, 3) depth points of the frame in the map frame (already range-limited).
        camera_map: (3,) camera centre in the map frame.
        up: (3,) unit up vector; ref_height: median camera height along `up`.
    """
    if len(points_map) == 0:
        return np.zeros(0, dtype=np.int64)
    axes = plane_axes(up)
    h = points_map @ up - ref_height
    lo, hi = params.height_band_m
    p = points_map[(h >= lo) & (h <= hi)]
    if len(p) == 0:
        return np.zeros(0, dtype=np.int64)
    return np.unique(_cell_heading_keys(p, camera_map, axes, params))


def keypoint_view_keys(
    K: NDArray[np.float64], keypoints: NDArray[np.floating], depth: NDArray[np.floating] | None,
    T_map_camera: NDArray[np.float64], up: NDArray[np.float64], ref_height: float, params: KeyframeParams,
) -> NDArray[np.int64]:
    """`coverage_keys` of one view from its keypoints (N, 2) pixels lifted with their depth (N,)
    metres (NaN = none; None: no keys) and its pose (4x4): what a stored keyframe, which keeps no
    depth image, saw."""
    if depth is None or len(keypoints) == 0:
        return np.zeros(0, dtype=np.int64)
    z = np.asarray(depth, np.float64).reshape(-1)
    ok = np.isfinite(z) & (z > 0) & (z <= params.max_depth_m)
    if not ok.any():
        return np.zeros(0, dtype=np.int64)
    pts = backproject_pixels(K, np.asarray(keypoints, np.float64).reshape(-1, 2)[ok], z[ok])
    T = np.asarray(T_map_camera, np.float64)
    return coverage_keys(pts @ T[:3, :3].T + T[:3, 3], T[:3, 3], up, ref_height, params)


def _cell_heading_keys(
    points_map: NDArray[np.float64], camera_map: NDArray[np.float64], axes: NDArray[np.float64],
    params: KeyframeParams,
) -> NDArray[np.int64]:
    """(N,) int64 key per point: its ground-plane cell and the heading bin of the direction from
    the camera to that cell's centre (`axes`: the (2, 3) plane axes)."""
    xy = points_map @ axes.T
    cxy = camera_map @ axes.T
    ij = np.floor(xy / params.cell_m).astype(np.int64)
    centres = (ij + 0.5) * params.cell_m
    ang = np.arctan2(centres[:, 1] - cxy[1], centres[:, 0] - cxy[0])
    b = np.floor((ang + np.pi) / (2 * np.pi) * params.heading_bins).astype(np.int64) % params.heading_bins
    keys: NDArray[np.int64] = ((ij[:, 0] + _OFF) * (2 * _OFF) + (ij[:, 1] + _OFF)) * 64 + b
    return keys


def coverage_keys_sliced(
    points_map: NDArray[np.float64], camera_map: NDArray[np.float64], up: NDArray[np.float64],
    params: KeyframeParams,
) -> NDArray[np.int64]:
    """Unique int64 keys of (cell, heading bin, absolute height slice) of one frame.

    Same cells and heading bins as `coverage_keys`, before the height band is applied;
    `band_keys` turns them into `coverage_keys`-style keys once the reference height is
    known. Args as `coverage_keys` (points already range-limited).
    """
    if len(points_map) == 0:
        return np.zeros(0, dtype=np.int64)
    axes = plane_axes(up)
    hs = np.clip(np.floor(points_map @ up / HEIGHT_QUANTUM_M).astype(np.int64) + _SLICES // 2, 0, _SLICES - 1)
    return np.unique(_cell_heading_keys(points_map, camera_map, axes, params) * _SLICES + hs)


def band_keys(sliced: NDArray[np.int64], ref_height: float, params: KeyframeParams) -> NDArray[np.int64]:
    """`coverage_keys_sliced` keys -> (cell, heading) keys whose slice centre is in the height band."""
    hs = sliced % _SLICES
    centre = (hs - _SLICES // 2 + 0.5) * HEIGHT_QUANTUM_M - ref_height
    lo, hi = params.height_band_m
    return np.unique(sliced[(centre >= lo) & (centre <= hi)] // _SLICES)


def budget_binds(n_selected: int, history: list[float], params: KeyframeParams) -> bool:
    """True if the explicit `budget` stopped the selection before the coverage target."""
    return (params.budget is not None and n_selected >= params.budget
            and (not history or history[-1] < params.coverage))


def greedy_select(cover: list[NDArray[np.int64]], params: KeyframeParams) -> tuple[list[int], list[float]]:
    """Greedy max-coverage (lazy evaluation, see module docstring).

    Args:
        cover: per candidate, the unique int64 keys it covers.
    Returns:
        (selected positions into `cover` in pick order, coverage fraction after each pick).
    """
    if not cover:
        return [], []
    sizes = [len(c) for c in cover]
    if sum(sizes) == 0:
        return [0], [1.0]
    universe, inv = np.unique(np.concatenate(cover), return_inverse=True)
    total = len(universe)
    ids = np.split(inv.astype(np.int64), np.cumsum(sizes)[:-1])
    covered = np.zeros(total, dtype=bool)
    heap = [(-n, c) for c, n in enumerate(sizes)]
    heapq.heapify(heap)
    selected: list[int] = []
    history: list[float] = []
    n_covered = 0
    cap = params.budget if params.budget is not None else len(cover)
    while heap and len(selected) < cap:
        _, c = heapq.heappop(heap)
        gain = int(np.count_nonzero(~covered[ids[c]]))
        if heap and (-gain, c) > heap[0]:
            heapq.heappush(heap, (-gain, c))  # stale bound: re-queue with the exact gain
            continue
        if gain < params.min_gain:
            break
        selected.append(c)
        covered[ids[c]] = True
        n_covered += gain
        history.append(n_covered / total)
        if history[-1] >= params.coverage:
            break
    return selected, history
