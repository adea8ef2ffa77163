"""Routes through a world and a waypoint follower that drives the closed-loop simulator.

* `plan_path`: shortest path on the world's clearance grid (minimum-cost path of
  `skimage.graph.route_through_array`, costs rising near walls), keeping the robot's
  radius plus a margin free.
* `pass_tasks`: the "map" pass visits every room (in a door-graph depth-first order,
  through corridors) and turns a full circle at each room centre, so the map sees every
  direction; "map-rooms" also turns a full circle halfway between the centre and each end
  of the room's long axis (as a person mapping a building walks a room, so views from near
  its walls are in the map too); a "query" pass visits the rooms in another (seeded) order
  at other spots with partial turns only.
* `follow`: a pure-pursuit controller with turn-in-place, run on `Simulator` at the
  odometry rate; returns ground truth and odometry without rendering.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Literal, TypeGuard

import numpy as np
from numpy.typing import NDArray

from litevloc.base.errors import LiteVLocError
from litevloc.sim.simulator import SimParams, Simulator, base_pose
from litevloc.sim.world import World

PassName = Literal["map", "query", "loop", "loop-lane", "loop-back", "map-rooms"]
PASS_NAMES: tuple[str, ...] = ("map", "query", "loop", "loop-lane", "loop-back", "map-rooms")
LOOP_BACK_LANE_M = 0.3  # "loop-lane" / "loop-back" drive this far off the corridor centre line, inner side


def is_pass_name(name: str) -> TypeGuard[PassName]:
    """Whether `name` is one of `PASS_NAMES` (narrows a string to `PassName`)."""
    return name in PASS_NAMES


class PlanningError(LiteVLocError, RuntimeError):
    """No collision-free path exists between two points."""


@dataclass(frozen=True)
class Task:
    kind: Literal["goto", "turn"]
    path: NDArray[np.float64] | None = None  # (N, 2) for goto
    angle: float = 0.0  # signed radians for turn


def plan_path(
    world: World, start: NDArray[np.floating], goal: NDArray[np.floating], radius: float
) -> NDArray[np.float64]:
    """(N, 2) waypoints (m, ~0.3 m apart) from start to goal avoiding walls and boxes."""
    from skimage.graph import route_through_array

    dist, res = world.clearance_grid
    margin = radius + 0.1
    cost = np.where(dist > margin, 1.0 + 1.5 / np.maximum(dist, 0.05), 1e6)
    s = (int(start[1] / res), int(start[0] / res))
    g = (int(goal[1] / res), int(goal[0] / res))
    for name, (i, j) in (("start", s), ("goal", g)):
        if not (0 <= i < dist.shape[0] and 0 <= j < dist.shape[1]) or dist[i, j] <= radius:
            raise PlanningError(f"{name} {(j * res, i * res)} is not free")
    idx, total = route_through_array(cost, s, g, fully_connected=True, geometric=True)
    if total >= 1e6:
        raise PlanningError(
            f"no path from {tuple(start)} to {tuple(goal)} with {margin:.2f} m clearance"
        )
    pts = (np.array(idx, dtype=np.float64)[:, ::-1] + 0.5) * res
    pts = pts[::3]
    if len(pts) >= 3:  # light smoothing, endpoints fixed
        sm = pts.copy()
        sm[1:-1] = (pts[:-2] + 2 * pts[1:-1] + pts[2:]) / 4
        pts = sm
    return np.vstack([pts, np.asarray(goal, dtype=np.float64)[None, :2]])


def _door_graph(world: World) -> dict[int, list[int]]:
    g: dict[int, list[int]] = {k: [] for k in world.regions}
    for a, b, *_ in world.doors:
        if b not in g[a]:
            g[a].append(b)
            g[b].append(a)
    return g


def _random_spot(
    world: World, label: int, rng: np.random.Generator, min_clear: float
) -> NDArray[np.float64]:
    import cv2

    dist, res = world.clearance_grid
    lab = cv2.resize(
        world.labels.astype(np.float32),
        (dist.shape[1], dist.shape[0]),
        interpolation=cv2.INTER_NEAREST,
    )
    ii, jj = np.nonzero((lab == label) & (dist > min_clear))
    if len(ii) == 0:
        return world.room_centre(label)
    k = int(rng.integers(len(ii)))
    return np.array([(jj[k] + 0.5) * res, (ii[k] + 0.5) * res])


def _side_spots(world: World, label: int, centre: NDArray[np.float64], clear: float) -> list[NDArray[np.float64]]:
    """Free spots of room `label` halfway from its centre to each end of its longer bbox axis."""
    x0, y0, x1, y1 = world.regions[label].bbox
    axis = np.array([1.0, 0.0]) if x1 - x0 >= y1 - y0 else np.array([0.0, 1.0])
    half = 0.25 * max(x1 - x0, y1 - y0)
    out = []
    for sign in (-1.0, 1.0):
        for frac in (1.0, 0.75, 0.5):  # nearer the centre where furniture is in the way
            p = centre + sign * frac * half * axis
            if world.is_free(p, clear) and world.region_at(p) == label:
                out.append(p)
                break
    return out


def pass_tasks(
    world: World, pass_name: PassName, seed: int, params: SimParams
) -> tuple[NDArray[np.float64], list[Task]]:
    """Start pose (4x4) and the task list of a map, query or loop pass.

    "loop" (layout "loop" worlds only): laps the ring corridor once and drives 10 m past
    the start again, for drift and loop-closure tests. "loop-lane": the same lap in the same
    direction, LOOP_BACK_LANE_M off the centre line (towards the inner wall) — a query pass
    that sees every place from another lane. "loop-back": that lane the other way round,
    where a forward-looking camera sees every wall from the side the mapping lap never faced.
    """
    if pass_name == "loop":
        return _loop_tasks(world, params)
    if pass_name == "loop-lane":
        return _loop_tasks(world, params, lane=LOOP_BACK_LANE_M)
    if pass_name == "loop-back":
        return _loop_tasks(world, params, reverse=True, lane=LOOP_BACK_LANE_M)
    mapping = pass_name in ("map", "map-rooms")
    rng = np.random.default_rng([seed, 17, 0 if mapping else 1])
    rooms = [k for k, r in world.regions.items() if r.kind == "room"]
    graph = _door_graph(world)
    if mapping:
        order: list[int] = []
        seen: set[int] = set()
        stack = [rooms[0]]
        while stack:  # depth-first over the door graph; rooms in visiting order
            k = stack.pop()
            if k in seen:
                continue
            seen.add(k)
            if world.regions[k].kind == "room":
                order.append(k)
            stack += sorted(graph[k], reverse=True)
        spots = [world.room_centre(k) for k in order]
        if pass_name == "map-rooms":
            spots = [p for k, c in zip(order, spots, strict=True)
                     for p in [c, *_side_spots(world, k, c, params.robot_radius + 0.3)]]
    else:
        order = [int(k) for k in rng.permutation(rooms)]
        spots = [_random_spot(world, k, rng, params.robot_radius + 0.5) for k in order]
    start_xy = spots[0]
    yaw0 = float(rng.uniform(-np.pi, np.pi))
    tasks: list[Task] = []
    cur = start_xy
    for i, xy in enumerate(spots):
        if i > 0:
            tasks.append(Task("goto", plan_path(world, cur, xy, params.robot_radius)))
            cur = xy
        if mapping:
            tasks.append(Task("turn", angle=2 * np.pi * (1 if i % 2 == 0 else -1)))
        else:
            tasks.append(Task("turn", angle=float(rng.uniform(-1.5, 1.5))))
    return base_pose(float(start_xy[0]), float(start_xy[1]), yaw0), tasks


def _loop_tasks(
    world: World, params: SimParams, reverse: bool = False, lane: float = 0.0
) -> tuple[NDArray[np.float64], list[Task]]:
    corridors = [r for r in world.regions.values() if r.kind == "corridor"]
    if world.spec.layout != "loop" or not corridors:
        raise PlanningError(
            f"pass 'loop' needs a world with layout 'loop'; "
            f"{world.spec.name} is '{world.spec.layout}'"
        )
    x0, y0, x1, y1 = corridors[0].bbox
    h = world.spec.corridor_width / 2 + lane
    corners = np.array([[x0 + h, y0 + h], [x1 - h, y0 + h], [x1 - h, y1 - h], [x0 + h, y1 - h]])
    start = np.array([x0 + h + 5.0, y0 + h])
    if reverse:
        start = np.array([x1 - h - 5.0, y0 + h])
        pts = [start, corners[0], corners[3], corners[2], corners[1], start, start - np.array([10.0, 0.0])]
    else:
        pts = [start, *corners[1:], corners[0], start, start + np.array([10.0, 0.0])]
    tasks = [
        Task("goto", plan_path(world, a, b, params.robot_radius))
        for a, b in itertools.pairwise(pts)
    ]
    return base_pose(float(start[0]), float(start[1]), np.pi if reverse else 0.0), tasks


def _wrap(a: float) -> float:
    return float((a + np.pi) % (2 * np.pi) - np.pi)


@dataclass
class FollowResult:
    """Kinematic run of a pass: base poses at the odometry rate and drift odometry."""

    t_ns: NDArray[np.int64]  # (N,)
    T_world_base: NDArray[np.float64]  # (N, 4, 4)
    speed: NDArray[np.float64]  # (N,) m/s
    T_odom_base: NDArray[np.float64]  # (N, 4, 4)
    collisions: int


def follow(
    world: World,
    params: SimParams,
    seed: int,
    start: NDArray[np.float64],
    tasks: list[Task],
    duration_s: float | None = None,
) -> FollowResult:
    """Drive the tasks with a pure-pursuit controller on a non-rendering `Simulator`."""
    sim = Simulator(world, params, seed, render=False)
    step = sim.reset(start)
    dt = 1.0 / params.odometry_rate_hz
    ts, Ts, sp, odo = [step.t_ns], [step.T_world_base], [0.0], [step.odometry[0].T_odom_base]
    v_prev, w_prev = 0.0, 0.0
    max_t = int((duration_s if duration_s is not None else 1e9) * 1e9)
    collisions = 0
    lookahead = 0.6
    for task in tasks:
        idx = 0
        turned = 0.0
        while ts[-1] < max_t:
            x, y, yaw = sim.state
            if task.kind == "turn":
                remaining = task.angle - turned
                if abs(remaining) < 0.02:
                    break
                v_cmd, w_cmd = (
                    0.0,
                    float(
                        np.sign(remaining) * min(params.cruise_omega, 2.0 * abs(remaining) + 0.1)
                    ),
                )
            else:
                path = task.path
                assert path is not None
                while (
                    idx < len(path) - 1 and np.hypot(path[idx, 0] - x, path[idx, 1] - y) < lookahead
                ):
                    idx += 1
                tx, ty = path[idx]
                dist_goal = np.hypot(path[-1, 0] - x, path[-1, 1] - y)
                if idx == len(path) - 1 and dist_goal < 0.15:
                    break
                err = _wrap(np.arctan2(ty - y, tx - x) - yaw)
                if abs(err) > 0.7:
                    v_cmd, w_cmd = 0.0, float(np.sign(err) * params.cruise_omega)
                else:
                    v_cmd = (
                        params.cruise_speed
                        * (1 - 0.6 * abs(err) / 0.7)
                        * min(1.0, dist_goal / 0.5 + 0.3)
                    )
                    w_cmd = float(
                        np.clip(2.0 * err, -params.cruise_omega * 1.5, params.cruise_omega * 1.5)
                    )
            # acceleration limits
            v_cmd = float(np.clip(v_cmd, v_prev - 1.0 * dt, v_prev + 1.0 * dt))
            w_cmd = float(np.clip(w_cmd, w_prev - 4.0 * dt, w_prev + 4.0 * dt))
            yaw_before = sim.state[2]
            step = sim.step(v_cmd, w_cmd, dt)
            turned += sim.state[2] - yaw_before
            v_prev, w_prev = (0.0, 0.0) if step.collided else (v_cmd, w_cmd)
            collisions += int(step.collided)
            for o in step.odometry:
                ts.append(o.t_ns)
                Ts.append(step.T_world_base)
                sp.append(v_prev)
                odo.append(o.T_odom_base)
            if step.collided and collisions > 200:
                break
        if ts[-1] >= max_t:
            break
    return FollowResult(
        np.array(ts, np.int64), np.stack(Ts), np.array(sp), np.stack(odo), collisions
    )
