"""Looking for a first fix: look around, then move to open space, in a synthetic walled room."""

from __future__ import annotations

import numpy as np
import pytest

from litevloc.base.params.sim import SimParams
from litevloc.base.params.sim_navigation import SearchParams
from litevloc.sim.local_planner import Command, LocalPlanner
from litevloc.sim.search import LocalizationSearch, free_length

P = SimParams()
K = P.intrinsics.K
# a level camera 0.5 m up at the base origin (optical z = base x, optical x = -base y)
T_BC = np.array([[0.0, 0.0, 1.0, 0.0], [-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 0.5], [0.0, 0.0, 0.0, 1.0]])
ROOM = (0.0, 0.0, 6.0, 5.0)  # x0, y0, x1, y1 (m): four walls


def pose(x: float, y: float, yaw: float) -> np.ndarray:
    T = np.eye(4)
    T[:2, :2] = [[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]]
    T[:2, 3] = x, y
    return T


Room = tuple[float, float, float, float]


def room_depth(x: float, y: float, yaw: float, room: Room = ROOM) -> np.ndarray:
    """Depth image (level camera at the base) of the room's walls, full height, seen from (x, y, yaw)."""
    u = np.arange(P.width)
    d_base = np.stack([np.ones(P.width), -(u - K[0, 2]) / K[0, 0]], 1)  # ray per column, base x = 1
    c, s = np.cos(yaw), np.sin(yaw)
    d = d_base @ np.array([[c, s], [-s, c]])  # to the world
    x0, y0, x1, y1 = room
    with np.errstate(divide="ignore", invalid="ignore"):
        tx = np.where(d[:, 0] > 0, (x1 - x) / d[:, 0], (x0 - x) / d[:, 0])
        ty = np.where(d[:, 1] > 0, (y1 - y) / d[:, 1], (y0 - y) / d[:, 1])
    z = np.minimum(np.where(np.isfinite(tx) & (tx > 0), tx, np.inf), np.where(np.isfinite(ty) & (ty > 0), ty, np.inf))
    return np.repeat(z[None, :], P.height, 0).astype(np.float32)


def clearance(x: float, y: float) -> float:
    x0, y0, x1, y1 = ROOM
    return min(x - x0, x1 - x, y - y0, y1 - y)


def run(start: tuple[float, float, float], seconds: float,
        room: Room = ROOM) -> tuple[LocalizationSearch, list[tuple[float, float, float, float, Command]]]:
    """Drive the search for `seconds` (unicycle steps of 0.2 s); (t, x, y, yaw, command) per step."""
    search = LocalizationSearch(LocalPlanner(), SearchParams())
    x, y, yaw = start
    dt, out = 0.2, []
    for k in range(int(seconds / dt)):
        T = pose(x, y, yaw)
        c = search.command(k * dt, T, room_depth(x, y, yaw, room), K, T_BC)
        out.append((k * dt, x, y, yaw, c))
        x, y, yaw = x + c.v * dt * np.cos(yaw), y + c.v * dt * np.sin(yaw), yaw + c.omega * dt
    return search, out


def test_free_length_is_the_nearest_point_ahead_within_the_half_width() -> None:
    pts = np.array([[2.0, 0.5], [3.0, 0.1], [-1.0, 0.0], [1.0, -0.9]])
    assert free_length(pts, 0.35, 4.0) == pytest.approx(3.0)
    assert free_length(pts, 0.6, 4.0) == pytest.approx(2.0)
    assert free_length(np.zeros((0, 2)), 0.35, 4.0) == 4.0


def test_first_look_is_a_full_turn_in_place() -> None:
    _, steps = run((0.8, 0.8, np.radians(225)), 12.0)  # in a corner, facing it
    assert all(c.v == 0.0 and c.reason == "search-look" for _, _, _, _, c in steps)
    turned = sum(abs(c.omega) * 0.2 for *_, c in steps)
    assert 0.8 * 2 * np.pi < turned < 2 * np.pi + 0.2


def test_from_a_corner_it_moves_into_open_space_without_touching_a_wall() -> None:
    search, steps = run((0.8, 0.8, np.radians(225)), 60.0)
    xy = np.array([(x, y) for _, x, y, _, _ in steps])
    moved = [c for *_, c in steps if c.v > 0]
    assert moved, "never left the corner"
    assert search.legs >= 2
    # it heads for the open middle of the room (where a mapping pass goes), not along a wall
    assert np.hypot(*(xy - (3.0, 2.5)).T).min() < 1.0
    assert min(clearance(x, y) for x, y in xy) > LocalPlanner().params.robot_radius
    # and spreads out: the spots it looked from are apart
    v = np.array(search.visited)
    assert len(v) >= 3 and min(np.hypot(*(v[i] - v[j])) for i in range(len(v)) for j in range(i)) > 0.5


def test_no_way_out_keeps_looking() -> None:
    # a box barely larger than the robot: no heading is free for min_leg_m, so it only turns
    search, steps = run((0.6, 0.6, 0.0), 40.0, room=(0.0, 0.0, 1.2, 1.2))
    assert search.legs == 0 and all(c.v == 0.0 for *_, c in steps)
    assert len(search.visited) == 1  # the same spot is not counted again after each fruitless look


def test_params_are_validated() -> None:
    with pytest.raises(ValueError):
        SearchParams(min_leg_m=2.0, leg_m=1.0)
    with pytest.raises(ValueError):
        SearchParams(omega=0.0)
