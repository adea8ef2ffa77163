"""Ground the simulated robot's camera has looked at (demo code for the local planner).

A forward camera with a limited field of view does not see what lies beside the robot: turning
while driving through a door swings the robot's inner side over ground that never was in view,
and a door jamb there is unknown, so an arc that counts unknown ground as free drives into it.
Each depth image marks the ground along every (strided) column's ray, from the camera to that
column's first obstacle point (or `max_range_m`; a column without depth counts as open to
`max_range_m`, as it yields no obstacle point), as seen; `unseen_distance` rasterises what was
seen around the robot on the local grid and returns the distance from each cell to the nearest
ground not seen, so arcs can refuse to sweep the robot over it. The same columns say which
remembered obstacle points the camera now sees past (`seen_through`: on ground it saw free, from
the column's nearest ground to short of its first obstacle), so the planner forgets them.

Frames: `base_link` x forward, y left, z up on the floor; the depth image is in the camera
optical frame mounted at `T_base_camera`; the local grid is centred on the robot, axis 0 = y,
axis 1 = x of the base frame, `grid_m` cells out to `grid_radius_m`.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from litevloc.base.params.sim_navigation import LocalPlannerParams


@dataclass(frozen=True)
class ColumnView:
    """What each `stride_px`-th column of one depth image saw along the ground, base frame: its
    horizontal unit direction from the camera (w, 2), the nearest ground it saw (`near`, m from the
    camera, horizontally: its lowest valid pixel; inf where none) and how far it saw free ground
    (`reach`: one `grid_m` cell short of its nearest obstacle point in the height band, at most
    `max_range_m`). `origin`: the camera's (2,) position in the base frame."""

    origin: NDArray[np.float64]
    direction: NDArray[np.float64]
    near: NDArray[np.float64]
    reach: NDArray[np.float64]


def column_view(
    depth: NDArray[np.floating], K: NDArray[np.floating], T_base_camera: NDArray[np.floating],
    params: LocalPlannerParams = LocalPlannerParams(),
) -> ColumnView:
    """The `ColumnView` of `depth` (HxW metres, NaN / <= 0 invalid; K 3x3; T_base_camera 4x4)."""
    p, s = params, params.stride_px
    d = np.asarray(depth, np.float64)[::s, ::s]
    v, u = np.mgrid[0 : depth.shape[0] : s, 0 : depth.shape[1] : s]
    ok = np.isfinite(d) & (d > 0.05) & (d < p.max_range_m)
    z = np.where(ok, d, 0.0)
    rays = np.stack([(u - K[0, 2]) / K[0, 0] * z, (v - K[1, 2]) / K[1, 1] * z, z], -1)
    T = np.asarray(T_base_camera, np.float64)
    P = rays @ T[:3, :3].T + T[:3, 3]  # (h, w, 3) base frame
    lo, hi = p.height_band_m
    band = ok & (P[..., 2] > lo) & (P[..., 2] < hi)
    horiz = np.hypot(P[..., 0] - T[0, 3], P[..., 1] - T[1, 3])
    reach = np.minimum(np.where(band, horiz, np.inf).min(axis=0), p.max_range_m) - p.grid_m  # (w,)
    near = np.where(ok, horiz, np.inf).min(axis=0)
    cols = np.arange(0, depth.shape[1], s)
    direction = np.stack([(cols - K[0, 2]) / K[0, 0], np.zeros(len(cols)), np.ones(len(cols))], 1) @ T[:3, :3].T
    direction = direction[:, :2] / np.linalg.norm(direction[:, :2], axis=1, keepdims=True)
    return ColumnView(T[:2, 3].copy(), direction, near, reach)


def seen_ray_points(view: ColumnView, params: LocalPlannerParams = LocalPlannerParams()) -> NDArray[np.float64]:
    """(N, 2) x, y (base frame, m) of the ground a depth image's `column_view` saw: every `grid_m`
    along each column's ray from the camera, stopping at the column's `reach` (one cell short of
    its nearest obstacle point in the height band)."""
    t = np.arange(0.0, params.max_range_m, params.grid_m)
    pts = view.origin + t[None, :, None] * view.direction[:, None, :]  # (w, T, 2)
    return np.asarray(pts[t[None, :] <= view.reach[:, None]], np.float64)


def seen_through(view: ColumnView, pts: NDArray[np.floating]) -> NDArray[np.bool_]:
    """(M,) whether each of `pts` (M, 2, base frame, m) lies on ground this view saw free: within
    the columns' fan, at least its column's `near` and short of its `reach` (the camera looks past
    it: what was there has moved away)."""
    q = np.asarray(pts, np.float64) - view.origin
    if not len(q) or not len(view.direction):
        return np.zeros(len(q), bool)
    r = np.hypot(q[:, 0], q[:, 1])
    ang = np.arctan2(view.direction[:, 1], view.direction[:, 0])  # (w,) the columns' bearings (rad, base frame)
    order = np.argsort(ang)
    a_sorted = ang[order]
    b = np.arctan2(q[:, 1], q[:, 0])
    k = np.clip(np.searchsorted(a_sorted, b), 1, len(a_sorted) - 1) if len(a_sorted) > 1 else np.zeros(len(b), int)
    if len(a_sorted) > 1:
        k = np.where(np.abs(a_sorted[k - 1] - b) < np.abs(a_sorted[k] - b), k - 1, k)
    col = order[k]
    step = float(np.median(np.abs(np.diff(a_sorted)))) if len(a_sorted) > 1 else 0.0
    inside = (b >= a_sorted[0] - step / 2) & (b <= a_sorted[-1] + step / 2)
    return np.asarray(inside & (r >= view.near[col]) & (r < view.reach[col]), bool)


def local_grid_cells(xy: NDArray[np.floating], grid_radius_m: float, grid_m: float) -> tuple[NDArray[np.int64], int]:
    """Cells (K, 2; axis 0 = base y, axis 1 = base x) of the points `xy` (M, 2, base frame, m)
    that fall on the robot-centred local grid, and the grid's side n (cells, odd; the robot at
    cell (n // 2, n // 2))."""
    c = round(grid_radius_m / grid_m)
    n = 2 * c + 1
    ij = np.round(np.asarray(xy, np.float64)[:, ::-1] / grid_m).astype(np.int64) + c
    return ij[np.all((ij >= 0) & (ij < n), axis=1)], n


def unseen_distance(seen_base: NDArray[np.floating], params: LocalPlannerParams) -> NDArray[np.float64]:
    """(n, n) distance (m) from each local-grid cell to the nearest cell of ground not seen, given
    the (M, 2) seen ground points (base frame, m). The robot's own footprint (radius + margin)
    counts as seen; seen cells are closed by one cell so the gaps between rays do not count."""
    p = params
    ij, n = local_grid_cells(seen_base, p.grid_radius_m, p.grid_m)
    c = n // 2
    rays = np.zeros((n, n), np.uint8)
    rays[ij[:, 0], ij[:, 1]] = 255
    seen = np.ascontiguousarray(cv2.dilate(rays, np.ones((3, 3), np.uint8)))
    cv2.circle(seen, (c, c), int(np.ceil((p.robot_radius + p.margin_m) / p.grid_m)), 255, -1)
    return np.asarray(cv2.distanceTransform(seen, cv2.DIST_L2, 5), np.float64) * p.grid_m


def grid_lookup(grid: NDArray[np.float64], xy: NDArray[np.floating], grid_m: float) -> NDArray[np.float64]:
    """Values of the robot-centred local `grid` (n, n) at the points `xy` (..., 2, base frame, m);
    0 outside the grid."""
    c = grid.shape[0] // 2
    ij = np.round(np.asarray(xy, np.float64)[..., ::-1] / grid_m).astype(np.int64) + c
    inside = np.all((ij >= 0) & (ij < grid.shape[0]), axis=-1)
    out = np.zeros(ij.shape[:-1])
    out[inside] = grid[ij[inside][:, 0], ij[inside][:, 1]]
    return out
