"""The support probe's random poses: free, uniform over the building, seeded."""

from __future__ import annotations

import numpy as np
import pytest

from litevloc.experiments.support_probe import random_base_poses
from litevloc.sim.world import load_world


def test_random_poses_are_free_spread_over_the_building_and_seeded() -> None:
    world = load_world("office")
    poses = random_base_poses(world, 40, seed=3, radius_m=0.3)
    assert len(poses) == 40
    xy = np.array([T[:2, 3] for T in poses])
    assert all(world.is_free(p, 0.3) for p in xy)
    assert len({world.region_at(p) for p in xy}) >= 4  # not one room
    yaw = np.array([np.arctan2(T[1, 0], T[0, 0]) for T in poses])
    assert np.ptp(yaw) > 5.0  # headings over the whole circle
    again = random_base_poses(world, 40, seed=3, radius_m=0.3)
    assert all(np.array_equal(a, b) for a, b in zip(poses, again, strict=True))
    assert not np.array_equal(poses[0], random_base_poses(world, 1, seed=4, radius_m=0.3)[0])


def test_a_building_without_room_for_the_robot_is_an_error() -> None:
    with pytest.raises(ValueError, match="free poses"):
        random_base_poses(load_world("office"), 3, seed=0, radius_m=50.0)
