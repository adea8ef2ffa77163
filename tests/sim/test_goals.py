"""The goal-image rule (`litevloc.sim.goals`, fixed before any navigation result): one goal per
room at a reachable free spot in the outer part of the room, facing into it, seen by the robot's
camera and by a hand-held camera 1.2-1.6 m up with a seeded tilt; seeded and independent of
what hangs on the walls."""

from __future__ import annotations

import numpy as np
import pytest

from litevloc.base.params.sim import SimParams
from litevloc.sim import goals as rule
from litevloc.sim.world import World, load_world


@pytest.fixture(scope="module")
def floor() -> World:
    return load_world("floor", seed=7)


def test_one_goal_per_room_at_a_reachable_spot_in_the_outer_part_facing_in(floor: World) -> None:
    rooms = {r.name: k for k, r in floor.regions.items() if r.kind == "room"}
    assert set(floor.goal_views) == set(rooms)
    dist, res = floor.clearance_grid
    reach = rule.reachable(floor)
    for name, view in floor.goal_views.items():
        T = view.T_world_base
        xy, yaw = T[:2, 3], float(np.arctan2(T[1, 0], T[0, 0]))
        i, j = int(xy[1] / res), int(xy[0] / res)
        assert floor.region_at(xy) == rooms[name] and reach[i, j]
        assert dist[i, j] >= 0.6 - 1e-6
        assert floor.is_free(xy, SimParams().robot_radius + 0.2)  # the grid is 0.1 m: exact clearance ~0.05 m less
        # facing into the room: its free space's middle within the jitter of the heading
        lab = rule._grid_labels(floor, dist.shape)
        mi, mj = np.nonzero((lab == rooms[name]) & (dist > 0.3))
        middle = (np.array([mj.mean(), mi.mean()]) + 0.5) * res
        to_mid = float(np.arctan2(*(middle - xy)[::-1]))
        assert abs(np.angle(np.exp(1j * (to_mid - yaw)))) <= np.radians(35.0) + 1e-6
        assert np.hypot(*(middle - xy)) > 0.5  # not in the middle: the outer part of the room


def test_hand_held_camera_height_tilt_and_place(floor: World) -> None:
    for view in floor.goal_views.values():
        Tb, Tc = view.T_world_base, view.T_world_camera_hand
        yaw = float(np.arctan2(Tb[1, 0], Tb[0, 0]))
        assert 1.2 <= Tc[2, 3] <= 1.6  # the hand-held height
        ahead = Tb[:2, 3] + 0.25 * np.array([np.cos(yaw), np.sin(yaw)])  # held 0.25 m in front
        assert np.allclose(Tc[:2, 3], ahead)
        z = Tc[:3, 2]  # optical axis: along the heading, pitched down by 0-15 deg
        pitch = np.degrees(np.arcsin(-z[2]))
        assert -1e-6 <= pitch <= 15.0 + 1e-6  # pitched down by up to 15 deg
        assert abs(np.angle(np.exp(1j * (np.arctan2(z[1], z[0]) - yaw)))) < 1e-6
        roll = np.degrees(np.arcsin(Tc[:3, 0] @ np.array([0.0, 0.0, 1.0]) * -1.0))
        assert abs(roll) <= 4.0 + 1e-6
    heights = [v.T_world_camera_hand[2, 3] for v in floor.goal_views.values()]
    assert np.ptp(heights) > 0.1  # drawn per room, not one height


def test_seeded_and_independent_of_the_pictures() -> None:
    a, b = load_world("office", seed=5), load_world("office", seed=5, appearance="aliased")
    c = load_world("office", seed=6)
    for name in a.goal_views:
        assert np.array_equal(a.goal_views[name].T_world_base, b.goal_views[name].T_world_base)
        assert np.array_equal(a.goal_views[name].T_world_camera_hand, b.goal_views[name].T_world_camera_hand)
    assert any(not np.allclose(a.goal_places[n][:2, 3], c.goal_places[n][:2, 3]) for n in a.goal_places)
    legacy = load_world("office-aliased")  # the first simulator's rule: in front of a poster, facing it
    assert legacy.spec.goal_rule == "poster" and len(legacy.goal_places) == 6
