"""The simulated robot's local planner drives through doors (ground-truth pose, depth rendered by
the simulator): through the middle of a door whose subgoal lies behind the wall at an angle (arcs
aimed straight at it dithered in front of the wall), and into a door turned towards from beside
it, whose inner jamb the camera never saw (arcs that counted unseen ground as free swung the
robot into it)."""

from __future__ import annotations

import numpy as np

from litevloc.base.params.sim import SimParams
from litevloc.base.params.sim_navigation import LocalPlannerParams
from litevloc.sim.elements import pose2d
from litevloc.sim.local_planner import Command, LocalPlanner
from litevloc.sim.simulator import Simulator
from litevloc.sim.spec import WorldSpec
from litevloc.sim.world import World


def _two_rooms() -> tuple[World, tuple[float, float, float]]:
    """Two empty 4 m rooms side by side and their door (x of the wall, y0, y1 of the opening)."""
    spec = WorldSpec(name="two-rooms", seed=1, rows=1, cols=2, room_size=(4.0, 4.0), room_size_jitter=0.0,
                     extra_door_prob=0.0, furniture_per_room=(0, 0), clutter_per_room=(0, 0),
                     posters_per_room=(0, 0))
    world = World(spec)
    (_a, _b, x0, y0, _x1, y1), = world.doors  # one door in the wall x = x0
    return world, (x0, y0, y1)


def _drive(world: World, start: np.ndarray, yaw: float, goal: np.ndarray,
           params: LocalPlannerParams = LocalPlannerParams()) -> tuple[Command | None, int, np.ndarray]:
    """Drive to `goal` (world x, y) for at most 30 s at 5 Hz: (the last command, collisions, where it ended)."""
    sim_params = SimParams()
    sim = Simulator(world, sim_params, seed=0)
    step = sim.reset(pose2d(*start, yaw))
    planner = LocalPlanner(params)
    depth, collisions, cmd = step.depth, 0, None
    for _ in range(150):
        g = np.linalg.inv(sim.T_world_base) @ np.array([*goal, 0.0, 1.0])
        cmd = planner.command(g[:2], depth, sim.K.K, sim_params.T_base_camera, sim.T_world_base)
        if cmd.reason == "arrived":
            break
        step = sim.step(cmd.v, cmd.omega, 0.2, color=False)
        depth, collisions = step.depth, collisions + int(step.collided)
    return cmd, collisions, np.round(sim.T_world_base[:2, 3], 2)


def test_local_planner_drives_through_a_door_to_a_subgoal_behind_the_wall() -> None:
    world, (x0, y0, y1) = _two_rooms()
    door_y = (y0 + y1) / 2
    side = -1.0 if door_y > 2.2 else 1.0
    start, goal = np.array([x0 - 1.3, door_y + side]), np.array([x0 + 1.3, door_y + side])  # 1 m off the door
    cmd, collisions, end = _drive(world, start, 0.0, goal)  # facing the wall, the subgoal straight ahead behind it
    assert cmd is not None and cmd.reason == "arrived", end
    assert collisions == 0


def test_turning_into_a_door_from_beside_it_does_not_swing_into_the_unseen_jamb() -> None:
    """0.9 m before the wall and 0.9 m beside the door, heading 80 deg off the wall's normal: the
    near jamb stays outside the 72 deg view all the way in. Counting that unseen ground as free,
    the arcs swung the robot's inner side into the jamb and kept pushing there."""
    world, (x0, y0, y1) = _two_rooms()
    start, goal = np.array([x0 - 0.9, y0 - 0.9]), np.array([x0 + 1.0, (y0 + y1) / 2])
    cmd, collisions, end = _drive(world, start, np.radians(80.0), goal)
    assert collisions == 0, end
    assert cmd is not None and cmd.reason == "arrived", end
