"""Unmapped openings of a map's occupancy grid: where mapped free space meets unknown space
that is wide enough to drive into and deep enough to be a place (a doorway seen but not
entered, a corridor whose end was never seen), so a team mapping a building knows where to
go back.

On the grid (`OccupancyGrid`: unknown / free / occupied cells):

1. free space is closed over gaps up to `close_m` (a floor or a wall seen from afar is
   speckled with unknown cells; they are no way anywhere);
2. frontier cells: free cells next to (4-neighbourhood) the remaining unknown cells;
3. frontier cells are grouped (8-neighbourhood); a group is an opening when it spans at least
   `min_width_m` (the longest extent of its cells) and the unknown space it touches holds at
   least `min_unknown_m2` within `look_m` of it (a shadow behind a cabinet is smaller).

Pure: a grid in, a list of `Opening`s out (largest unknown area first).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from litevloc.base.params.navigation import OpeningParams
from litevloc.pipelines.topomap.types import OccupancyGrid


@dataclass(frozen=True)
class Opening:
    """One unmapped opening. Plane coordinates are the grid's (`OccupancyGrid.to_plane`)."""

    centre_xy: NDArray[np.float64]  # (2,) plane coordinates (m) of its frontier cells' mean
    position: NDArray[np.float64]  # (3,) the same point in the map frame (at the plane's origin height)
    width_m: float  # longest extent of its frontier cells
    direction: NDArray[np.float64]  # (3,) unit, map frame: from mapped space into the unknown
    unknown_m2: float  # unknown area it leads to, within look_m
    cells: int  # frontier cells


def _disk(radius_cells: int) -> NDArray[np.uint8]:
    k = 2 * radius_cells + 1
    return np.asarray(cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k)), np.uint8)


def mapped_free(grid: OccupancyGrid, params: OpeningParams = OpeningParams()) -> NDArray[np.bool_]:
    """(H, W) the grid's free space closed over gaps up to `close_m` (step 1 of the module
    docstring): what the map knows to be free."""
    cells = np.asarray(grid.cells)
    free = cells == OccupancyGrid.FREE
    close = round(params.close_m / float(grid.resolution))
    if close > 0 and cells.size:
        occ = cells == OccupancyGrid.OCCUPIED
        free = (cv2.morphologyEx(free.astype(np.uint8), cv2.MORPH_CLOSE, _disk(close)) > 0) & ~occ
    return np.asarray(free)


def find_openings(grid: OccupancyGrid, params: OpeningParams = OpeningParams()) -> list[Opening]:
    """Openings of `grid` into unknown space (see the module docstring), largest first."""
    cells = np.asarray(grid.cells)
    if cells.size == 0:
        return []
    res = float(grid.resolution)
    free = mapped_free(grid, params)
    unknown = (cells == OccupancyGrid.UNKNOWN) & ~free
    unk_u8 = unknown.astype(np.uint8)
    cross = np.array([[0, 1, 0], [1, 1, 1], [0, 1, 0]], np.uint8)
    frontier = free & (cv2.dilate(unk_u8, cross) > 0)
    n, labels = cv2.connectedComponents(frontier.astype(np.uint8), connectivity=8)
    if n <= 1:
        return []
    _, unk_labels = cv2.connectedComponents(unk_u8, connectivity=4)
    near = _disk(max(1, round(params.look_m / res)))
    out: list[Opening] = []
    for k in range(1, n):
        ii, jj = np.nonzero(labels == k)
        pts = np.stack([jj, ii], 1).astype(np.float64)
        width = _extent(pts) * res + res
        if width < params.min_width_m:
            continue
        mask = (labels == k).astype(np.uint8)
        touching = np.unique(unk_labels[(cv2.dilate(mask, cross) > 0) & unknown])
        behind = np.isin(unk_labels, touching[touching > 0]) & (cv2.dilate(mask, near) > 0)
        area = float(behind.sum()) * res * res
        if area < params.min_unknown_m2:
            continue
        bi, bj = np.nonzero(behind)
        d = np.array([bj.mean() - jj.mean(), bi.mean() - ii.mean()])
        d = d / max(float(np.linalg.norm(d)), 1e-9)
        centre = grid.origin + (np.array([jj.mean(), ii.mean()]) + 0.5) * res
        out.append(Opening(centre, centre @ grid.plane_axes, round(width, 3), d @ grid.plane_axes, round(area, 2),
                           len(ii)))
    return sorted(out, key=lambda o: -o.unknown_m2)


def _extent(pts: NDArray[np.float64]) -> float:
    """Longest distance (cells) between two of the (N, 2) points (along their principal axis)."""
    if len(pts) < 2:
        return 0.0
    c = pts - pts.mean(axis=0)
    axis = np.linalg.svd(c, full_matrices=False)[2][0]
    proj = c @ axis
    return float(proj.max() - proj.min())


def openings_summary(openings: list[Opening]) -> list[dict[str, object]]:
    """JSON-able rows: where each opening is (map frame, m), how wide, which way, how much is behind it."""
    return [{"x": round(float(o.position[0]), 2), "y": round(float(o.position[1]), 2),
             "z": round(float(o.position[2]), 2), "width_m": o.width_m,
             "direction": [round(float(v), 2) for v in o.direction], "unknown_m2": o.unknown_m2}
            for o in openings]
