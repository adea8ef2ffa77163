"""The simulated robot's local planner drives through a door whose subgoal lies behind the wall
at an angle (ground-truth pose, depth rendered by the simulator): the local path leads it
through the middle of the door; arcs aimed straight at the subgoal dithered in front of the wall."""

from __future__ import annotations

import numpy as np

from litevloc.base.params.sim import SimParams
from litevloc.sim.elements import pose2d
from litevloc.sim.local_planner import LocalPlanner
from litevloc.sim.simulator import Simulator
from litevloc.sim.spec import WorldSpec
from litevloc.sim.world import World


def test_local_planner_drives_through_a_door_to_a_subgoal_behind_the_wall() -> None:
    spec = WorldSpec(name="two-rooms", seed=1, rows=1, cols=2, room_size=(4.0, 4.0), room_size_jitter=0.0,
                     extra_door_prob=0.0, furniture_per_room=(0, 0), clutter_per_room=(0, 0),
                     posters_per_room=(0, 0))
    world = World(spec)
    (_a, _b, x0, y0, _x1, y1), = world.doors  # one door in the wall x = x0
    door_y = (y0 + y1) / 2
    side = -1.0 if door_y > 2.2 else 1.0
    start, goal = np.array([x0 - 1.3, door_y + side]), np.array([x0 + 1.3, door_y + side])  # 1 m off the door
    params = SimParams()
    sim = Simulator(world, params, seed=0)
    step = sim.reset(pose2d(*start, 0.0))  # facing the wall, the subgoal straight ahead behind it
    planner = LocalPlanner()
    depth, collisions, cmd = step.depth, 0, None
    for _ in range(150):  # 30 s at 5 Hz
        g = np.linalg.inv(sim.T_world_base) @ np.array([*goal, 0.0, 1.0])
        cmd = planner.command(g[:2], depth, sim.K.K, params.T_base_camera, sim.T_world_base)
        if cmd.reason == "arrived":
            break
        step = sim.step(cmd.v, cmd.omega, 0.2, color=False)
        depth, collisions = step.depth, collisions + int(step.collided)
    assert cmd is not None and cmd.reason == "arrived", np.round(sim.T_world_base[:2, 3], 2)
    assert collisions == 0
