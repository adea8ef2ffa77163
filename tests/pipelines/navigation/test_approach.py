"""The final approach planned on a small occupancy grid: a reachable place, one around an
obstacle, one behind a wall (refused), one that cannot be reached (refused), one inside an
obstacle's margin (approached at the free cell next to it)."""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np

from litevloc.base.params.navigation import TrackerParams
from litevloc.pipelines.navigation.approach import plan_approach
from litevloc.pipelines.topomap.types import OccupancyGrid

R = 0.1  # m per cell
P = TrackerParams(approach_radius_m=0.2, approach_snap_m=0.3, approach_detour_m=2.0)


def room(h_m: float = 6.0, w_m: float = 6.0) -> np.ndarray:
    """(H, W) free floor with an occupied border; cell (i, j) spans x = j*R.., y = i*R.. (metres)."""
    c = np.full((round(h_m / R), round(w_m / R)), OccupancyGrid.FREE, np.uint8)
    c[0, :] = c[-1, :] = c[:, 0] = c[:, -1] = OccupancyGrid.OCCUPIED
    return c


def grid(cells: np.ndarray) -> OccupancyGrid:
    return OccupancyGrid(cells, np.zeros(2), R, np.array([0, 0, 1.0]), np.eye(3)[:2])


def at(x: float, y: float) -> np.ndarray:
    return np.array([x, y, 0.3])


def test_a_place_in_clear_sight_is_one_straight_leg_ending_on_it() -> None:
    a = plan_approach(grid(room()), at(1.0, 1.0), at(3.0, 2.5), P)
    assert a.ok and a.reason == "ok" and a.waypoints is not None
    assert len(a.waypoints) == 1
    np.testing.assert_allclose(a.waypoints[-1], [3.0, 2.5, 0.3])
    assert np.isclose(a.straight_m, 2.5) and a.straight_m <= a.length_m <= a.straight_m + 0.3


def test_a_place_behind_a_table_is_reached_around_it_with_clearance() -> None:
    c = room()
    c[20:40, 28:32] = OccupancyGrid.OCCUPIED  # a 2 m long obstacle between start and place
    g = grid(c)
    a = plan_approach(g, at(1.5, 3.0), at(4.5, 3.0), P)
    assert a.ok and a.waypoints is not None and len(a.waypoints) >= 2
    assert 3.0 + 0.5 < a.length_m < 3.0 + P.approach_detour_m
    # every leg keeps the robot's radius from the obstacle
    pts = np.vstack([at(1.5, 3.0), a.waypoints])
    for p, q in itertools.pairwise(pts):
        s = p[:2] + np.linspace(0, 1, 200)[:, None] * (q[:2] - p[:2])
        dx = np.maximum.reduce([2.8 - s[:, 0], np.zeros(len(s)), s[:, 0] - 3.2])
        dy = np.maximum.reduce([2.0 - s[:, 1], np.zeros(len(s)), s[:, 1] - 4.0])
        assert np.hypot(dx, dy).min() >= P.approach_radius_m - R / 2  # the grid's resolution
    np.testing.assert_allclose(a.waypoints[-1], [4.5, 3.0, 0.3])


def test_a_place_behind_a_wall_is_refused_as_contradicting_the_map() -> None:
    c = room(6.0, 10.0)
    c[:, 50:52] = OccupancyGrid.OCCUPIED  # a wall at x = 5 m ...
    c[50:58, 50:52] = OccupancyGrid.FREE  # ... with a door 5.0-5.8 m up
    a = plan_approach(grid(c), at(4.2, 1.0), at(5.8, 1.0), P)  # 1.6 m straight, ~9 m round by the door
    assert not a.ok and a.waypoints is None
    assert "behind a wall" in a.reason or "not reachable" in a.reason
    near_door = plan_approach(grid(c), at(4.2, 4.6), at(5.8, 4.6), P)  # the door is a short detour here
    assert near_door.ok and near_door.length_m > near_door.straight_m + 0.3


def test_the_detour_bound_decides_between_going_round_and_refusing() -> None:
    c = room(6.0, 10.0)
    c[:, 50:52] = OccupancyGrid.OCCUPIED
    c[11:20, 50:52] = OccupancyGrid.FREE  # a door 1.1-2.0 m up, 0.5 m beside the straight line
    ok = plan_approach(grid(c), at(4.5, 1.0), at(5.7, 1.0), P)
    assert ok.ok and ok.straight_m + 0.2 < ok.length_m < ok.straight_m + P.approach_detour_m
    tight = dataclasses.replace(P, approach_detour_m=0.2)
    no = plan_approach(grid(c), at(4.5, 1.0), at(5.7, 1.0), tight)
    assert not no.ok and "behind a wall from its node" in no.reason and np.isclose(no.length_m, ok.length_m)


def test_an_unreachable_place_is_refused_with_the_reason() -> None:
    c = room()
    c[:, 30:32] = OccupancyGrid.OCCUPIED  # a wall with no door
    a = plan_approach(grid(c), at(1.0, 3.0), at(4.5, 3.0), P)
    assert not a.ok and "not reachable on the map's grid" in a.reason
    inside = room()
    inside[25:40, 25:40] = OccupancyGrid.OCCUPIED  # the place 0.7 m deep inside a big obstacle
    b = plan_approach(grid(inside), at(1.0, 1.0), at(3.2, 3.2), P)
    assert not b.ok and "lies in an obstacle" in b.reason


def test_a_place_in_an_obstacles_margin_is_approached_at_the_free_cell_next_to_it() -> None:
    c = room()
    c[29:31, 20:40] = OccupancyGrid.OCCUPIED  # a bench at y = 2.9-3.1 m
    a = plan_approach(grid(c), at(3.0, 1.0), at(3.0, 2.75), P)  # 0.15 m from it: inside the 0.2 m margin
    assert a.ok and a.waypoints is not None
    end = a.waypoints[-1]
    assert 0.05 <= a.snapped_m <= P.approach_snap_m + R / 2
    assert end[1] <= 2.9 - P.approach_radius_m + R and np.isclose(np.linalg.norm(end[:2] - [3.0, 2.75]),
                                                                    a.snapped_m, atol=1e-6)
