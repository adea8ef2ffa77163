"""The final approach: from the goal node to the goal image's own place, planned on the map's
occupancy grid.

The goal node is the keyframe that verified the goal image; the place where the image was
taken (its PnP pose, projected to the floor) is usually a metre or two from it. The way
there is planned on the occupancy grid: OCCUPIED cells grown by the robot's radius are
blocked, FREE and UNKNOWN cells are not (the local planner sees what the mapping pass did
not). A place inside an obstacle's margin is approached at the nearest reachable cell within
`approach_snap_m`. A place whose grid path from its node is more than `approach_detour_m`
longer than the straight line lies behind a wall from the keyframe that saw the same view:
the placement contradicts the map and the goal is refused rather than driven to.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray
from scipy.sparse.csgraph import dijkstra

from litevloc.base.params.navigation import TrackerParams
from litevloc.pipelines.topomap.types import OccupancyGrid

_STEPS = ((0, 1), (1, 0), (1, 1), (1, -1))  # 8-connectivity, each edge once


@dataclass(frozen=True)
class Approach:
    """A planned final approach.

    waypoints: (K, 3) map-frame points from the first turn to the approach's end (the goal
    place, or the free cell next to it), at the start's height; None when refused.
    length_m: grid path length (m); inf when refused for want of a path.
    straight_m: straight distance start -> goal place on the floor plane (m).
    snapped_m: how far the approach's end lies from the goal place (m).
    reason: "ok", or why the place cannot be approached.
    """

    waypoints: NDArray[np.float64] | None
    length_m: float
    straight_m: float
    snapped_m: float
    reason: str

    @property
    def ok(self) -> bool:
        return self.waypoints is not None


def blocked_cells(cells: NDArray[np.uint8], radius_cells: float) -> NDArray[np.bool_]:
    """(H, W) True where a robot centre (at a cell's centre) would come within `radius_cells`
    of any part of an OCCUPIED cell (to half a cell: offsets up to radius + 0.5 cells)."""
    occ = (cells == OccupancyGrid.OCCUPIED).astype(np.uint8)
    if radius_cells <= 0:
        return np.asarray(occ, bool)
    r = int(np.ceil(radius_cells + 0.5))
    yy, xx = np.mgrid[-r:r + 1, -r:r + 1]
    disc = (np.hypot(yy, xx) <= radius_cells + 0.5).astype(np.uint8)
    return np.asarray(cv2.dilate(occ, disc), bool)


def grid_distances(free: NDArray[np.bool_], start: tuple[int, int], resolution: float,
                   ) -> tuple[NDArray[np.float64], NDArray[np.int32]]:
    """Dijkstra over the 8-connected `free` cells of an (H, W) mask from cell `start`:
    (H, W) path lengths in metres (inf: unreachable) and (H, W) predecessor flat indices."""
    H, W = free.shape
    idx = np.arange(H * W).reshape(H, W)
    rows, cols, wts = [], [], []
    for di, dj in _STEPS:
        a = (slice(max(0, -di), H - max(0, di)), slice(max(0, -dj), W - max(0, dj)))
        b = (slice(max(0, -di) + di, H - max(0, di) + di), slice(max(0, -dj) + dj, W - max(0, dj) + dj))
        both = free[a] & free[b]
        ia, ib = idx[a][both], idx[b][both]
        w = np.full(len(ia), resolution * float(np.hypot(di, dj)))
        rows += [ia, ib]
        cols += [ib, ia]
        wts += [w, w]
    G = sp.csr_matrix((np.concatenate(wts), (np.concatenate(rows), np.concatenate(cols))), shape=(H * W, H * W))
    dist, prev = dijkstra(G, directed=True, indices=int(idx[start]), return_predecessors=True)
    return dist.reshape(H, W), prev.reshape(H, W)


def _line_free(free: NDArray[np.bool_], a: NDArray[np.intp], b: NDArray[np.intp]) -> bool:
    """True if every cell sampled along the straight line a -> b (row, col) is free."""
    n = int(np.ceil(2 * np.abs(b - a).max())) + 1
    ij = np.rint(a + np.linspace(0, 1, max(n, 2))[:, None] * (b - a)).astype(np.intp)
    return bool(free[ij[:, 0], ij[:, 1]].all())


def simplify(free: NDArray[np.bool_], cells: NDArray[np.intp]) -> NDArray[np.intp]:
    """(M, 2) cell path -> the cells where it must turn: from each kept cell, the farthest
    later cell in straight free line (string pulling); the last cell is always kept."""
    if len(cells) == 1:
        return cells
    out = [0]
    while out[-1] < len(cells) - 1:
        i = out[-1]
        j = len(cells) - 1
        while j > i + 1 and not _line_free(free, cells[i], cells[j]):
            j -= 1
        out.append(j)
    return cells[out[1:]]


def _nearest_free(free: NDArray[np.bool_], at: NDArray[np.float64], within: float) -> tuple[int, int] | None:
    """The free cell (row, col) nearest to fractional cell `at` within `within` cells; None if none."""
    H, W = free.shape
    r = int(np.ceil(within))
    i0, j0 = int(np.floor(at[0])), int(np.floor(at[1]))
    best, best_d = None, float("inf")
    for i in range(max(0, i0 - r), min(H, i0 + r + 1)):
        for j in range(max(0, j0 - r), min(W, j0 + r + 1)):
            d = float(np.hypot(i + 0.5 - at[0], j + 0.5 - at[1]))
            if free[i, j] and d <= within + 0.5 and d < best_d:
                best, best_d = (i, j), d
    return best


def plan_approach(grid: OccupancyGrid, start: NDArray[np.floating], place: NDArray[np.floating],
                  params: TrackerParams) -> Approach:
    """The final approach from `start` (3,) to the goal `place` (3,) (map frame, metres) on
    `grid`; see the module docstring. An empty grid gives the straight line."""
    start3, place3 = np.asarray(start, np.float64)[:3], np.asarray(place, np.float64)[:3]
    s_xy, p_xy = grid.to_plane(np.stack([start3, place3]))
    straight = float(np.linalg.norm(p_xy - s_xy))
    height = float(start3 @ grid.up)

    def to_map(xy: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.asarray(xy @ grid.plane_axes + height * grid.up, np.float64)

    if grid.cells.size == 0:
        return Approach(to_map(p_xy[None]), straight, straight, 0.0, "ok")
    r = grid.resolution
    rad = params.approach_radius_m / r
    # every path within straight + detour lies in this box (an ellipse with foci start and place)
    pad = params.approach_detour_m / 2 + params.approach_snap_m + r
    lo = np.floor((np.minimum(s_xy, p_xy) - pad - grid.origin) / r).astype(int)[::-1] - int(np.ceil(rad)) - 1
    hi = np.ceil((np.maximum(s_xy, p_xy) + pad - grid.origin) / r).astype(int)[::-1] + int(np.ceil(rad)) + 2
    H, W = grid.cells.shape
    window = np.full(tuple(hi - lo), OccupancyGrid.UNKNOWN, np.uint8)
    src = grid.cells[max(lo[0], 0):min(hi[0], H), max(lo[1], 0):min(hi[1], W)]
    window[max(-lo[0], 0):max(-lo[0], 0) + src.shape[0], max(-lo[1], 0):max(-lo[1], 0) + src.shape[1]] = src
    free = ~blocked_cells(window, rad)
    origin = grid.origin + lo[::-1] * r  # plane coordinates of the window's cell (0, 0) corner

    def frac(xy: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.asarray(((xy - origin) / r)[::-1], np.float64)

    start_cell = _nearest_free(free, frac(s_xy), params.approach_snap_m / r)
    if start_cell is None:
        return Approach(None, float("inf"), straight, float("nan"),
                        f"the approach's start is inside an obstacle's margin on the map's grid "
                        f"(no free cell within {params.approach_snap_m:g} m)")
    dist, prev = grid_distances(free, start_cell, r)
    snap = params.approach_snap_m / r
    at = frac(p_xy)
    ii, jj = np.nonzero(free)
    d_cells = np.hypot(ii + 0.5 - at[0], jj + 0.5 - at[1])
    near = d_cells <= snap + 0.5
    if not near.any():
        return Approach(None, float("inf"), straight, float("nan"),
                        f"the goal place lies in an obstacle on the map's grid (no free cell within "
                        f"{params.approach_snap_m:g} m of it)")
    reach = near & np.isfinite(dist[ii, jj])
    if not reach.any():
        return Approach(None, float("inf"), straight, float("nan"),
                        f"the goal place ({straight:.2f} m away) is not reachable on the map's grid "
                        f"within {straight + params.approach_detour_m:.1f} m")
    k = int(np.flatnonzero(reach)[np.argmin(d_cells[reach])])
    end = (int(ii[k]), int(jj[k]))
    length = float(dist[end])
    snapped = float(d_cells[k]) * r
    if length > straight + params.approach_detour_m:
        return Approach(None, length, straight, snapped,
                        f"the goal place lies behind a wall from its node: {length:.1f} m on the map's grid "
                        f"for {straight:.1f} m straight (> +{params.approach_detour_m:g} m); its placement "
                        "contradicts the map")
    path = [end]
    while path[-1] != start_cell:
        f = int(prev[path[-1]])
        path.append((f // free.shape[1], f % free.shape[1]))
    cells = np.array(path[::-1], np.intp)
    turns = simplify(free, cells).astype(np.float64) + 0.5
    xy = origin + turns[:, ::-1] * r
    if snapped < r:  # the place itself is free: end exactly on it
        xy[-1] = p_xy
    return Approach(to_map(xy), length, straight, snapped, "ok")
