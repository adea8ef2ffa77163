"""The 2D occupancy grid of the map, from depth points of the mapping pass.

Heights are measured along `up` relative to the median camera height. A cell is
OCCUPIED if it holds at least `min_points` points inside the obstacle band, FREE if it
holds points below the band (floor level) and none in it, or if a camera passed over it,
UNKNOWN otherwise.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from litevloc.base.params.mapping import OccupancyParams
from litevloc.pipelines.topomap.keyframes import plane_axes
from litevloc.pipelines.topomap.types import OccupancyGrid


def build_occupancy(
    points_map: NDArray[np.float64], camera_positions: NDArray[np.float64], up: NDArray[np.float64],
    params: OccupancyParams,
) -> OccupancyGrid:
    """Grid from (N, 3) map-frame points and (M, 3) camera centres (the mapping trajectory)."""
    u = np.asarray(up, dtype=np.float64)
    u = u / np.linalg.norm(u)
    axes = plane_axes(u)
    ref = float(np.median(camera_positions @ u)) if len(camera_positions) else 0.0
    cam_xy = camera_positions @ axes.T
    pts = np.asarray(points_map, dtype=np.float64).reshape(-1, 3)
    xy = pts @ axes.T
    allxy = np.concatenate([xy, cam_xy]) if len(xy) else cam_xy
    if len(allxy) == 0:
        raise ValueError("cannot build an occupancy grid from no points and no cameras")
    lo = allxy.min(axis=0) - params.margin_m
    hi = allxy.max(axis=0) + params.margin_m
    r = params.resolution_m
    W = int(np.ceil((hi[0] - lo[0]) / r)) + 1
    H = int(np.ceil((hi[1] - lo[1]) / r)) + 1
    grid = OccupancyGrid(np.zeros((H, W), np.uint8), lo, r, u, axes)
    h = pts @ u - ref
    band_lo, band_hi = params.obstacle_band_m
    obstacle = (h >= band_lo) & (h <= band_hi)
    floor = h < band_lo

    def counts(sel: NDArray[np.bool_]) -> NDArray[np.int64]:
        ij = grid.cell_of(xy[sel])
        c = np.zeros((H, W), np.int64)
        np.add.at(c, (ij[:, 0], ij[:, 1]), 1)
        return c

    occ = counts(obstacle) >= params.min_points
    free = (counts(floor) > 0) & ~occ
    cells = grid.cells
    cells[free] = OccupancyGrid.FREE
    cij = grid.cell_of(cam_xy)
    cells[cij[:, 0], cij[:, 1]] = OccupancyGrid.FREE
    cells[occ] = OccupancyGrid.OCCUPIED
    cells[cij[:, 0], cij[:, 1]] = OccupancyGrid.FREE  # the camera was there: traversable
    return grid


def segment_is_free(grid: OccupancyGrid, a_xy: NDArray[np.floating], b_xy: NDArray[np.floating]) -> bool:
    """True if the straight plane segment a->b crosses no OCCUPIED cell (sampled at res/2)."""
    a = np.asarray(a_xy, dtype=np.float64)
    b = np.asarray(b_xy, dtype=np.float64)
    n = max(2, int(np.ceil(np.linalg.norm(b - a) / (grid.resolution / 2))) + 1)
    s = np.linspace(0, 1, n)[:, None]
    ij = grid.cell_of(a + s * (b - a))
    H, W = grid.cells.shape
    inside = (ij[:, 0] >= 0) & (ij[:, 0] < H) & (ij[:, 1] >= 0) & (ij[:, 1] < W)
    if not np.all(inside):
        return False
    return not bool(np.any(grid.cells[ij[:, 0], ij[:, 1]] == OccupancyGrid.OCCUPIED))
