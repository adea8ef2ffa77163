"""Routes through a world and a waypoint follower that drives the closed-loop simulator.

* `plan_path`: shortest path on the world's clearance grid (minimum-cost path of
  `skimage.graph.route_through_array`, costs rising steeply near walls so that a path
  through a door keeps to its middle), keeping the robot's radius plus a margin free.
* `pass_tasks`: the "map" pass drives as an operator mapping a building would: into every
  room and along every corridor (in a door-graph depth-first order); in each room a full
  turn at its centre, then `EDGE_SPOTS` spots in the outer part of the room, far apart, at
  each a sweep of +-`EDGE_SWEEP_RAD` around the way into the room (the views a person gets
  who photographs the room from its edge); a full turn at spots `CORRIDOR_SPACING_M` apart
  along each corridor, its ends included. "map-rooms" turns a full circle at the centre and
  halfway to each end of every room's long axis (corridors only driven through); a "query"
  pass visits the rooms in another (seeded) order at other spots with partial turns only.
* `follow`: a pure-pursuit controller with turn-in-place, run on `Simulator` at the
  odometry rate; returns ground truth and odometry without rendering. Its short lookahead
  (`LOOKAHEAD_M`) keeps it on the planned path through doors (a longer one cut the corner
  of a door, pushed against its jamb and never reached the rooms behind it).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from functools import cached_property
from typing import Literal, TypeGuard

import numpy as np
from numpy.typing import NDArray

from litevloc.base.errors import LiteVLocError
from litevloc.base.geometry import invert
from litevloc.base.params.drift import DriftParams
from litevloc.base.params.sim import SimParams
from litevloc.pipelines.odometry_drift import IncrementalDrift
from litevloc.sim.goals import reachable
from litevloc.sim.simulator import base_pose
from litevloc.sim.world import World

PassName = Literal["map", "query", "loop", "loop-lane", "loop-back", "map-rooms"]
PASS_NAMES: tuple[str, ...] = ("map", "query", "loop", "loop-lane", "loop-back", "map-rooms")
LOOP_BACK_LANE_M = 0.3  # "loop-lane" / "loop-back" drive this far off the corridor centre line, inner side
EDGE_SPOTS = 3  # "map": spots in the outer part of each room, looking into it
EDGE_CLEAR_M = 0.6  # an edge spot stands this far from every wall and box (grid clearance, m)
EDGE_SWEEP_RAD = np.radians(60.0)  # "map": at an edge spot the camera sweeps +-this around the way into the room
CORRIDOR_SPACING_M = 8.0  # "map": corridors are driven to spots this far apart (covering their ends), turning at each
LOOKAHEAD_M = 0.35  # the follower steers toward the path point this far ahead
TURN_IN_PLACE_RAD = 0.5  # the follower turns in place while the path point is farther off its heading


def is_pass_name(name: str) -> TypeGuard[PassName]:
    """Whether `name` is one of `PASS_NAMES` (narrows a string to `PassName`)."""
    return name in PASS_NAMES


class PlanningError(LiteVLocError, RuntimeError):
    """No collision-free path exists between two points."""


@dataclass(frozen=True)
class Task:
    kind: Literal["goto", "turn", "face"]
    path: NDArray[np.float64] | None = None  # (N, 2) for goto
    angle: float = 0.0  # turn: signed radians to turn; face: the heading to turn to (world yaw, radians)


def plan_path(
    world: World, start: NDArray[np.floating], goal: NDArray[np.floating], radius: float
) -> NDArray[np.float64]:
    """(N, 2) waypoints (m, ~0.3 m apart) from start to goal avoiding walls and boxes."""
    from skimage.graph import route_through_array

    dist, res = world.clearance_grid
    margin = radius + 0.1
    # the steep term below 0.7 m keeps a path in the middle of a 1 m door
    cost = np.where(dist > margin, 1.0 + 1.5 / np.maximum(dist, 0.05) + 8.0 * np.clip(0.7 - dist, 0.0, None), 1e6)
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
    for i, (a, b, *_) in enumerate(world.doors):
        if i in world.closed_doors:  # a closed leaf blocks it (a changed building)
            continue
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


def _edge_spots(world: World, label: int, centre: NDArray[np.float64]) -> list[tuple[NDArray[np.float64], float]]:
    """`EDGE_SPOTS` spots in the outer part of room `label` (as far from each other as they can
    be), each with the heading toward the middle of the room's free space; nearest first from
    `centre`. Where a person stands to photograph a room, the operator looks into it too."""
    import cv2

    dist, res = world.clearance_grid
    lab = cv2.resize(world.labels.astype(np.float32), (dist.shape[1], dist.shape[0]),
                     interpolation=cv2.INTER_NEAREST)
    ii, jj = np.nonzero((lab == label) & reachable(world) & (dist >= EDGE_CLEAR_M))
    mi, mj = np.nonzero((lab == label) & (dist > 0.3))
    if len(ii) == 0 or len(mi) == 0:
        return []
    middle = (np.array([mj.mean(), mi.mean()]) + 0.5) * res
    pts = (np.stack([jj, ii], 1) + 0.5) * res
    from_mid = np.hypot(*(pts - middle).T)
    pts = pts[from_mid >= 0.4 * from_mid.max()]
    picked = [int(np.argmax(np.hypot(*(pts - middle).T)))]
    d = np.hypot(*(pts - pts[picked[0]]).T)
    while len(picked) < EDGE_SPOTS and d.max() > 1.0:
        picked.append(int(np.argmax(d)))
        d = np.minimum(d, np.hypot(*(pts - pts[picked[-1]]).T))
    chosen = sorted((pts[k] for k in picked), key=lambda p: float(np.hypot(*(p - centre))))
    return [(p, float(np.arctan2(*(middle - p)[::-1]))) for p in chosen]


def _side_spots(world: World, label: int, centre: NDArray[np.float64], clear: float,
                min_length: float = 0.0) -> list[NDArray[np.float64]]:
    """Free spots of room `label` halfway from its centre to each end of its longer bbox axis
    (none when that axis is shorter than `min_length` m)."""
    x0, y0, x1, y1 = world.regions[label].bbox
    if max(x1 - x0, y1 - y0) < min_length:
        return []
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


def _corridor_spots(world: World, label: int, here: NDArray[np.float64], radius: float) -> list[NDArray[np.float64]]:
    """Spots along corridor `label`, `CORRIDOR_SPACING_M` apart (farthest-point sampling of its
    free cells, starting with the one farthest from `here`), visited nearest first from `here`."""
    import cv2

    dist, res = world.clearance_grid
    lab = cv2.resize(world.labels.astype(np.float32), (dist.shape[1], dist.shape[0]),
                     interpolation=cv2.INTER_NEAREST)
    ii, jj = np.nonzero((lab == label) & (dist > radius + 0.35))
    if len(ii) == 0:
        return []
    pts = (np.stack([jj, ii], 1) + 0.5) * res
    picked = [int(np.argmax(np.hypot(*(pts - here).T)))]
    d = np.hypot(*(pts - pts[picked[0]]).T)
    while d.max() > CORRIDOR_SPACING_M:
        picked.append(int(np.argmax(d)))
        d = np.minimum(d, np.hypot(*(pts - pts[picked[-1]]).T))
    out, cur, left = [], here, [pts[k] for k in picked]
    while left:
        k = int(np.argmin([np.hypot(*(p - cur)) for p in left]))
        cur = left.pop(k)
        out.append(cur)
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
        while stack:  # depth-first over the door graph; regions in visiting order
            k = stack.pop()
            if k in seen:
                continue
            seen.add(k)
            if world.regions[k].kind == "room" or pass_name == "map":
                order.append(k)
            stack += sorted(graph[k], reverse=True)
        # (spot, look): look None = a full turn there; a heading = a sweep of +-EDGE_SWEEP_RAD around it
        spots: list[tuple[NDArray[np.float64], float | None]] = []
        for k in order:
            if world.regions[k].kind == "corridor":
                here = spots[-1][0] if spots else world.room_centre(k)
                spots += [(p, None) for p in _corridor_spots(world, k, here, params.robot_radius)]
                continue
            c = world.room_centre(k)
            if pass_name == "map-rooms":
                spots += [(p, None) for p in [c, *_side_spots(world, k, c, params.robot_radius + 0.3)]]
            else:
                spots += [(c, None), *_edge_spots(world, k, c)]
    else:
        order = [int(k) for k in rng.permutation(rooms)]
        spots = [(_random_spot(world, k, rng, params.robot_radius + 0.5), 0.0) for k in order]
    start_xy = spots[0][0]
    yaw0 = float(rng.uniform(-np.pi, np.pi))
    tasks: list[Task] = []
    cur = start_xy
    for i, (xy, look) in enumerate(spots):
        if i > 0:
            tasks.append(Task("goto", plan_path(world, cur, xy, params.robot_radius)))
            cur = xy
        if not mapping:
            tasks.append(Task("turn", angle=float(rng.uniform(-1.5, 1.5))))
        elif look is None:
            tasks.append(Task("turn", angle=2 * np.pi * (1 if i % 2 == 0 else -1)))
        else:
            tasks += [Task("face", angle=look - EDGE_SWEEP_RAD), Task("turn", angle=2 * EDGE_SWEEP_RAD)]
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


def _clamp(a: float, lo: float, hi: float) -> float:
    """`np.clip` of one float (same value; the follower calls it four times per tick, where
    numpy's per-call overhead was most of a pass's planning time)."""
    return min(max(a, lo), hi)


def _wrap(a: float) -> float:
    return float((a + np.pi) % (2 * np.pi) - np.pi)


@dataclass
class FollowResult:
    """Kinematic run of a pass: base poses at the odometry rate and drift odometry."""

    t_ns: NDArray[np.int64]  # (N,)
    T_world_base: NDArray[np.float64]  # (N, 4, 4)
    speed: NDArray[np.float64]  # (N,) m/s
    collisions: int
    drift: DriftParams
    seed: int

    @cached_property
    def T_odom_base(self) -> NDArray[np.float64]:
        """(N, 4, 4) drift-model odometry of the run (`IncrementalDrift` seeded with `seed`,
        one step per odometry tick; computed when first asked for: a map build never reads it)."""
        drift = IncrementalDrift(self.drift, self.seed)
        out = [np.eye(4)]
        for k in range(1, len(self.t_ns)):
            D = invert(self.T_world_base[k - 1]) @ self.T_world_base[k]
            out.append(drift.step(D, (int(self.t_ns[k]) - int(self.t_ns[k - 1])) * 1e-9))
        return np.stack(out)


def _track(path: list[list[float]], idx: int, x: float, y: float, yaw: float,
           params: SimParams) -> tuple[float, float, int, bool]:
    """Pure pursuit on `path` ((N, 2) waypoints as lists: indexing numpy per tick cost more
    than the arithmetic) from waypoint `idx`: (v, omega, new idx, arrived)."""
    while idx < len(path) - 1 and np.hypot(path[idx][0] - x, path[idx][1] - y) < LOOKAHEAD_M:
        idx += 1
    tx, ty = path[idx]
    dist_goal = float(np.hypot(path[-1][0] - x, path[-1][1] - y))
    if idx == len(path) - 1 and dist_goal < 0.15:
        return 0.0, 0.0, idx, True
    err = _wrap(float(np.arctan2(ty - y, tx - x)) - yaw)
    if abs(err) > TURN_IN_PLACE_RAD:
        return 0.0, float(np.sign(err) * params.cruise_omega), idx, False
    v = params.cruise_speed * (1 - 0.6 * abs(err) / TURN_IN_PLACE_RAD) * min(1.0, dist_goal / 0.5 + 0.3)
    return v, float(np.clip(2.5 * err, -params.cruise_omega * 1.5, params.cruise_omega * 1.5)), idx, False


def follow(
    world: World,
    params: SimParams,
    seed: int,
    start: NDArray[np.float64],
    tasks: list[Task],
    duration_s: float | None = None,
) -> FollowResult:
    """Drive the tasks with a pure-pursuit controller (turning in place where the path turns
    sharply): unicycle kinematics at the odometry rate, stopped by walls and boxes as
    `Simulator` is (a tick that would touch one does not move and counts as a collision)."""
    period = round(1e9 / params.odometry_rate_hz)
    dt = period * 1e-9
    x, y = float(start[0, 3]), float(start[1, 3])
    yaw = float(np.arctan2(start[1, 0], start[0, 0]))
    if not world.is_free(np.array([x, y]), params.robot_radius):
        raise PlanningError(f"start ({x:.2f}, {y:.2f}) is not free for radius {params.robot_radius} m")
    poses, speeds = [(x, y, yaw)], [0.0]
    v_prev, w_prev = 0.0, 0.0
    max_ticks = int((duration_s if duration_s is not None else 1e7) / dt)
    collisions = 0
    for task in tasks:
        idx, turned = 0, 0.0
        waypoints = None if task.path is None else task.path.tolist()
        while len(poses) <= max_ticks:
            if task.kind in ("turn", "face"):
                remaining = task.angle - turned if task.kind == "turn" else _wrap(task.angle - yaw)
                if abs(remaining) < 0.02:
                    break
                v_cmd, w_cmd = 0.0, float(np.sign(remaining) * min(params.cruise_omega, 2.0 * abs(remaining) + 0.1))
            else:
                assert waypoints is not None
                v_cmd, w_cmd, idx, arrived = _track(waypoints, idx, x, y, yaw, params)
                if arrived:
                    break
            # acceleration limits
            v_cmd = _clamp(v_cmd, v_prev - 1.0 * dt, v_prev + 1.0 * dt)
            w_cmd = _clamp(w_cmd, w_prev - 4.0 * dt, w_prev + 4.0 * dt)
            v_cmd = _clamp(v_cmd, -params.max_speed, params.max_speed)
            w_cmd = _clamp(w_cmd, -params.max_omega, params.max_omega)
            mid = yaw + 0.5 * w_cmd * dt
            nx, ny = x + v_cmd * dt * np.cos(mid), y + v_cmd * dt * np.sin(mid)
            if world.is_free(np.array([nx, ny]), params.robot_radius):
                x, y, yaw = float(nx), float(ny), yaw + w_cmd * dt
                turned += w_cmd * dt
                v_prev, w_prev = v_cmd, w_cmd
            else:
                collisions += 1
                v_prev, w_prev = 0.0, 0.0
            poses.append((x, y, yaw))
            speeds.append(v_prev)
            if collisions > 200:
                raise PlanningError(f"the pass is stuck at ({x:.2f}, {y:.2f}): {collisions} collisions")
        if len(poses) > max_ticks:
            break
    P = np.array(poses)
    c, s_ = np.cos(P[:, 2]), np.sin(P[:, 2])
    T = np.tile(np.eye(4), (len(P), 1, 1))
    T[:, 0, 0], T[:, 0, 1], T[:, 1, 0], T[:, 1, 1] = c, -s_, s_, c
    T[:, 0, 3], T[:, 1, 3] = P[:, 0], P[:, 1]
    t = np.arange(len(P), dtype=np.int64) * period
    return FollowResult(t, T, np.array(speeds), collisions, params.drift, seed)
