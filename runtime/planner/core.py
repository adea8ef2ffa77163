"""The goal planner's core (`GoalPlanner`): goal images and fused poses in, typed outputs out.

No I/O: the node (`runtime.planner.node.PlannerService`) decodes the messages, feeds them here in
arrival order and publishes what comes back, a `PlannerStatus` or a `Subgoal`, in that order.
The algorithms are in `pipelines.navigation` (goal placement `planner.localize_goal`, the path
follower `tracker.SubgoalTracker`, the final approach `approach.plan_approach`); this module is
the goal queue around them: goals visited in order, cancelled, failed when the robot makes no
progress, and reached only within `tracker.reach_m` of the goal image's place where the map
gives one.

It lives in `runtime/` rather than `pipelines/` because it is session state, not an algorithm:
a queue, sequence numbers, publish throttling and the `planner` config section (`config` is
above `pipelines` in the layers).
"""

from __future__ import annotations

import dataclasses
import itertools
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from litevloc.base.geometry import invert
from litevloc.config.schema import PlannerConfig
from litevloc.pipelines.navigation.approach import Approach, plan_approach
from litevloc.pipelines.navigation.candidates import GoalResult
from litevloc.pipelines.navigation.planner import localize_goal
from litevloc.pipelines.navigation.tracker import NavState, NavStatus, SubgoalTracker
from litevloc.pipelines.topomap.types import TopoMap

LocateFn = Callable[[NDArray[np.uint8]], GoalResult]


def decode_goal_image(data: bytes) -> NDArray[np.uint8]:
    """JPEG/PNG bytes -> HxWx3 uint8 RGB; ValueError when undecodable."""
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    if img is None or img.ndim != 3 or min(img.shape[:2]) < 16:
        raise ValueError(f"goal image is not a decodable colour JPEG/PNG ({len(data)} bytes)")
    return np.ascontiguousarray(img[:, :, ::-1])


def goal_locator(topomap: TopoMap, extract: Callable[[Any], Any], describe: Callable[[Any], Any],
                 match: Callable[[Any, Any], Any], params: PlannerConfig) -> LocateFn:
    """`locate(rgb) -> GoalResult` with the map's intrinsics scaled to the goal image."""
    K0 = np.asarray(topomap.K[0], np.float64)
    w0, h0 = (int(v) for v in topomap.image_size[0])

    def locate(rgb: NDArray[np.uint8]) -> GoalResult:
        h, w = rgb.shape[:2]
        K = K0.copy()
        K[0] *= w / w0
        K[1] *= h / h0
        return localize_goal(extract(rgb), describe(rgb), K, topomap, match, params.goal)

    return locate


def level_pose(T: NDArray[np.float64]) -> NDArray[np.float64]:
    """Keep x, y, z and the yaw of a 4x4 pose (z up); roll and pitch removed."""
    yaw = float(np.arctan2(T[1, 0], T[0, 0]))
    out = np.eye(4)
    out[:2, :2] = [[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]]
    out[:3, 3] = T[:3, 3]
    return out


@dataclass(frozen=True)
class Subgoal:
    """Where to drive next, stamped with the pose it answers (`t_ns`, sensor time).

    `goal`: the active goal's name; `final`: on the final approach to the goal image's place,
    with `legs_left` of its grid path's points still to reach (a node's subgoal: 0)."""

    t_ns: int
    node: int
    T_map_subgoal: NDArray[np.float64]  # 4x4 base pose at the node, map frame
    T_base_subgoal: NDArray[np.float64]  # 4x4 the same in the robot frame
    goal: str | None = None
    final: bool = False
    legs_left: int = 0


@dataclass(frozen=True)
class PlannerStatus:
    """The planner's state, published as JSON on every change (`as_dict`; see the node's topics).

    `seq` increases on every change; `pose_t_ns`: stamp of the last pose handled; `busy`: a goal
    active or queued; `remaining_m`: path length left (m)."""

    state: NavState
    reason: str
    goal: str | None
    goal_node: int | None
    subgoal_node: int | None
    path: tuple[int, ...]
    remaining_m: float
    queued: int
    goals_received: int
    seq: int
    pose_t_ns: int | None
    replans: int
    busy: bool

    def as_dict(self) -> dict[str, Any]:
        """The JSON object of `litevloc/planner_status` (`state` its string, `path` a list)."""
        out = dataclasses.asdict(self)
        out["state"], out["path"] = str(self.state.value), list(self.path)
        return out


Output = PlannerStatus | Subgoal


@dataclass(frozen=True)
class Placement:
    """Where a goal image is (`result`; `result.node` None: refused, `result.reason` says why) and,
    where the map gives its metric place, the level base pose there (4x4, map frame) and the
    final approach to it from its node."""

    result: GoalResult
    goal_base: NDArray[np.float64] | None = None
    approach: Approach | None = None


@dataclass(frozen=True)
class QueuedGoal:
    name: str
    node: int
    placement: Placement


class GoalPlanner:
    """Goal images and fused poses -> `PlannerStatus` and `Subgoal` outputs (no I/O).

    Ordering contract: every call returns its outputs in the order they are to be published;
    for every pose handled while a goal is active or queued there is a subgoal or a status
    stamped with that pose (with `publish_period_s` 0).

    Args:
        topomap: the map (node camera poses, connectivity graph, occupancy grid).
        locate: goal image (HxWx3 uint8 RGB) -> `GoalResult`.
        params: the `planner` config section.
        T_base_camera: 4x4 camera pose in the base frame (node poses are camera poses).
        on_placed: called with each goal image's placement, in arrival order (a run's record).
    """

    def __init__(self, topomap: TopoMap, locate: LocateFn, params: PlannerConfig,
                 T_base_camera: NDArray[np.float64], on_placed: Callable[[Placement], None] | None = None) -> None:
        self.map, self.locate, self.params = topomap, locate, params
        self.on_placed = on_placed
        self.T_base_camera = np.asarray(T_base_camera, np.float64)
        self.T_camera_base = invert(self.T_base_camera)
        # where the base stands at each node: the keyframe camera pose moved back to the base, level
        self.node_base = np.stack([level_pose(T @ self.T_camera_base) for T in topomap.T_map_camera])
        self.tracker = SubgoalTracker(topomap, params.tracker, self.node_base[:, :3, 3])
        self.queue: deque[QueuedGoal] = deque()
        self.active: str | None = None
        self.goals_received = 0
        self.seq = 0
        self.pose: tuple[int, NDArray[np.float64]] | None = None
        self.status = self._status(NavState.IDLE, "no goal", None)
        self._last_pub_t: int | None = None
        self._last_sub: tuple[int | None, tuple[float, float, float] | None] | None = None  # (node, via)
        self._nav: NavStatus | None = None
        self._goal_base: NDArray[np.float64] | None = None  # metric goal of the active goal (map frame)
        self._final = False  # driving from the goal node to the goal image's own place
        self._approach: Approach | None = None  # the active goal's final approach, planned from its node
        self._waypoints: list[NDArray[np.float64]] = []  # final approach points still to reach (map frame)
        self._progress: tuple[float, int] | None = None  # (closest remaining m, its t_ns) of the active goal

    # ----------------------------------------------------------------- helpers
    def _status(self, state: NavState, reason: str, goal: str | None, nav: NavStatus | None = None,
                goal_node: int | None = None) -> PlannerStatus:
        self.seq += 1
        return PlannerStatus(
            state=state, reason=reason, goal=goal, goal_node=goal_node,
            subgoal_node=None if nav is None else nav.subgoal,
            path=() if nav is None else tuple(nav.path),
            remaining_m=0.0 if nav is None else round(float(nav.remaining_m), 3),
            queued=len(self.queue), goals_received=self.goals_received, seq=self.seq,
            pose_t_ns=None if self.pose is None else self.pose[0], replans=self.tracker.replans, busy=self.busy)

    def _emit(self, out: list[Output], state: NavState, reason: str, goal: str | None,
              nav: NavStatus | None = None, goal_node: int | None = None) -> None:
        self.status = self._status(state, reason, goal, nav, goal_node)
        out.append(self.status)

    @property
    def busy(self) -> bool:
        """A goal is active or queued."""
        return self.active is not None or bool(self.queue)

    @property
    def approach_left(self) -> tuple[NDArray[np.float64], ...]:
        """The final approach's points (3,) still to reach, map frame (empty off the final approach)."""
        return tuple(self._waypoints) if self._final else ()

    def robot_position(self, T_map_base: NDArray[np.float64]) -> NDArray[np.float64]:
        """Base position of the robot in the map (compared with `node_base` positions)."""
        return np.asarray(T_map_base, np.float64)[:3, 3]

    def subgoal_of(self, node: int, t_ns: int, T_map_base: NDArray[np.float64],
                   via: tuple[float, float, float] | None = None) -> Subgoal:
        """The subgoal to publish: `node`'s base pose, or on the way there the grid path's next
        turn `via` (map frame, metres), or on the final approach its next turn or end."""
        final = self._final and self._goal_base is not None
        T_map_sub = (self._goal_base if final and self._goal_base is not None else self.node_base[node]).copy()
        if final and self._waypoints:  # the final approach's next turn or its end, with the place's heading
            T_map_sub[:3, 3] = self._waypoints[0]
        elif not final and via is not None:
            T_map_sub[:3, 3] = via
        return Subgoal(t_ns, node, T_map_sub, invert(T_map_base) @ T_map_sub, self.active, self._final,
                       len(self._waypoints))

    def goal_base_pose(self, res: GoalResult) -> NDArray[np.float64] | None:
        """Where the base should stand for the goal image (level, at the goal node's height),
        or None when the map gave no metric goal pose or the final approach is off."""
        if res.T_map_goal is None or res.node is None or not self.params.tracker.final_approach:
            return None
        T = level_pose(np.asarray(res.T_map_goal, np.float64) @ self.T_camera_base)
        T[2, 3] = self.node_base[res.node, 2, 3]
        return T

    def active_goal_place(self) -> Subgoal | None:
        """Where the active goal is: the goal image's place (level base pose), or its node's base
        pose where the map gave no place; None without an active goal or a pose."""
        node = self.tracker.goal
        if self.active is None or node is None or self.pose is None:
            return None
        T_goal = (self._goal_base if self._goal_base is not None else self.node_base[node]).copy()
        return Subgoal(self.pose[0], node, T_goal, invert(self.pose[1]) @ T_goal, self.active)

    def place(self, image: NDArray[np.uint8]) -> Placement:
        """Where the goal image is (`locate`) and, where the map gives its metric place, the final
        approach to it from its node; a place the approach cannot reach from its node comes back
        refused (`result.node` None, the approach's reason)."""
        res = self.locate(image)
        goal_base = None if res.node is None else self.goal_base_pose(res)
        if res.node is None or goal_base is None:
            return Placement(res)
        approach = plan_approach(self.map.grid, self.node_base[res.node, :3, 3], goal_base[:3, 3],
                                 self.params.tracker)
        if not approach.ok:
            return Placement(dataclasses.replace(res, node=None, reason=f"placed at node {res.node}, refused: "
                                                 f"{approach.reason}"))
        return Placement(res, goal_base, approach)

    # ----------------------------------------------------------------- inputs
    def reject_goal(self, name: str, why: str) -> list[Output]:
        """A goal message that could not be read (`why`): counted and reported failed."""
        self.goals_received += 1
        out: list[Output] = []
        self._emit(out, NavState.FAILED, f"goal {name!r}: undecodable message: {why}", name)
        return out

    def add_goal(self, name: str, image: bytes | NDArray[np.uint8]) -> list[Output]:
        """Localize a goal image and queue it (starts at once if idle and a pose is known)."""
        out: list[Output] = []
        self.goals_received += 1
        try:
            if isinstance(image, bytes | bytearray | memoryview):
                if len(image) > self.params.max_goal_bytes:
                    raise ValueError(f"goal image of {len(image)} bytes > planner.max_goal_bytes")
                image = decode_goal_image(bytes(image))
            if len(self.queue) >= self.params.max_queued_goals:
                raise ValueError(f"goal queue full ({self.params.max_queued_goals} goals)")
            placed = self.place(image)
        except Exception as exc:
            self._emit(out, NavState.FAILED, f"goal {name!r} rejected: {exc}", name)
            return out
        if self.on_placed is not None:
            self.on_placed(placed)
        res, approach = placed.result, placed.approach
        if res.node is None:
            self._emit(out, NavState.FAILED, f"goal {name!r}: {res.reason}", name)
            return out
        self.queue.append(QueuedGoal(name, res.node, placed))
        where = f"goal {name!r} at node {res.node} ({res.inliers} inliers)"
        if placed.goal_base is not None and approach is not None:
            where += (f", its place {approach.straight_m:.2f} m from the node ({res.pose_inliers} PnP inliers; "
                      f"{approach.length_m:.2f} m on the grid)")
        was_active = self.active
        if self.active is None:
            self._start_next(out)
        if self.active is None and self.pose is None:
            self._emit(out, NavState.IDLE, f"{where} queued; waiting for a fused pose", None)
        elif was_active is not None:
            self._emit(out, NavState.PLANNED, f"{where} queued behind {was_active!r}", was_active, self._nav,
                       self.tracker.goal)
        return out

    def cancel(self, what: str) -> list[Output]:
        """`current`: fail the active goal and go on; `all`: also drop the queue."""
        out: list[Output] = []
        if what not in ("current", "all"):
            self._emit(out, self.status.state, f"unknown cancel request {what!r} (current|all)", self.active)
            return out
        if what == "all":
            self.queue.clear()
        if self.active is not None:
            name, self.active, self._final = self.active, None, False
            self._emit(out, NavState.FAILED, f"goal {name!r} cancelled", name, goal_node=self.tracker.goal)
        self._start_next(out)
        if what == "all" and self.active is None:
            self._emit(out, NavState.IDLE, "all goals cancelled", None)
        return out

    def _start_next(self, out: list[Output]) -> None:
        while self.active is None and self.queue and self.pose is not None:
            goal = self.queue.popleft()
            name, node = goal.name, goal.node
            T = self.pose[1]
            nav = self.tracker.set_goal(node, self.robot_position(T))
            if nav.state is NavState.FAILED:
                self._emit(out, NavState.FAILED, f"goal {name!r}: {nav.reason}", name, goal_node=node)
                continue
            self.active, self._nav = name, nav
            self._goal_base, self._approach = goal.placement.goal_base, goal.placement.approach
            self._final, self._progress = False, None
            self._waypoints = []
            self._last_sub = None
            self._emit(out, NavState.PLANNED, f"goal {name!r}: {nav.reason}", name, nav, node)
            self._publish_subgoal(out, nav, force=True)

    def _publish_subgoal(self, out: list[Output], nav: NavStatus, force: bool = False) -> None:
        assert self.pose is not None and nav.subgoal is not None
        t_ns, T = self.pose
        period_ns = round(self.params.publish_period_s * 1e9)
        due = (force or self._last_pub_t is None or (nav.subgoal, nav.via) != self._last_sub
               or t_ns - self._last_pub_t >= period_ns)
        if due:
            self._last_pub_t, self._last_sub = t_ns, (nav.subgoal, nav.via)
            out.append(self.subgoal_of(nav.subgoal, t_ns, T, nav.via))

    def _finish(self, out: list[Output], state: NavState, reason: str) -> None:
        """The active goal ends (reached or failed, with `reason`); the next queued one starts."""
        name, self.active, self._final = self.active, None, False
        self._emit(out, state, f"goal {name!r}: {reason}", name, goal_node=self.tracker.goal)
        self._start_next(out)

    def on_pose(self, t_ns: int, T_map_base: NDArray[np.floating]) -> list[Output]:
        """A fused pose (sensor time ns, 4x4 `T_map_base`): advance / replan / reach; returns what to publish."""
        out: list[Output] = []
        T = np.asarray(T_map_base, np.float64)
        self.pose = (int(t_ns), T)
        if self.active is None:
            self._start_next(out)
            return out
        if self._stalled(out):
            return out
        if self._final:
            return self._final_approach(out, T)
        before = self.tracker.replans
        nav = self._nav = self.tracker.update(self.robot_position(T))
        if nav.state is NavState.REACHED and self._goal_base is not None:
            self._begin_final_approach(out, T, nav)
            return self._final_approach(out, T)
        if nav.state in (NavState.REACHED, NavState.FAILED):
            self._finish(out, nav.state, nav.reason)
        else:
            changed = self.tracker.replans != before or nav.subgoal != self.status.subgoal_node
            if changed and self._progress is not None and nav.remaining_m > self._progress[0]:
                # a new plan (a replan, or a leg's detour round a wall) made the way longer: progress
                # counts on it from here, or a robot driving the detour is failed as stalled
                self._progress = None
            if changed:
                why = "replanned (strayed from the path)" if self.tracker.replans != before else "next subgoal"
                self._emit(out, NavState.PLANNED, f"goal {self.active!r}: {why}", self.active, nav, self.tracker.goal)
            self._publish_subgoal(out, nav)
        return out

    def _begin_final_approach(self, out: list[Output], T: NDArray[np.float64], nav: NavStatus) -> None:
        """At the goal node: on along the grid path to the goal image's place, replanned from where
        the robot stands (within reach_m of the node), the node's plan where that fails."""
        node = self.tracker.goal
        assert node is not None and self._approach is not None and self._goal_base is not None
        here = plan_approach(self.map.grid, self.robot_position(T), self._goal_base[:3, 3], self.params.tracker)
        way = here if here.ok else self._approach
        assert way.waypoints is not None
        self._waypoints = list(way.waypoints)
        self._final, self._progress = True, None  # progress counts on the approach's length now
        self._emit(out, NavState.PLANNED, f"goal {self.active!r}: at node {node}; on to the goal image's place "
                   f"{way.straight_m:.2f} m away ({way.length_m:.2f} m on the grid, {len(self._waypoints)} legs)",
                   self.active, nav, node)

    def _stalled(self, out: list[Output]) -> bool:
        """Fail the active goal when the robot has come no `stall_progress_m` closer to it (path
        length left, or the straight distance on the final approach) in `stall_s` of sensor time."""
        p = self.params.tracker
        if p.stall_s <= 0 or self.active is None or self._nav is None or self.pose is None:
            return False
        t_ns = self.pose[0]
        left = float(self._nav.remaining_m)
        if self._progress is None or left <= self._progress[0] - p.stall_progress_m or t_ns < self._progress[1]:
            self._progress = (left, t_ns)
            return False
        if (t_ns - self._progress[1]) * 1e-9 < p.stall_s:
            return False
        self._finish(out, NavState.FAILED, f"no progress for {p.stall_s:g} s ({left:.1f} m left, closest "
                     f"{self._progress[0]:.1f} m): blocked?")
        return True

    def _final_approach(self, out: list[Output], T: NDArray[np.float64]) -> list[Output]:
        """From the goal node along the grid path's turns to the goal image's place (subgoal = the
        next turn, then that place); reached only within `reach_m` of the place."""
        assert self._goal_base is not None and self.pose is not None
        node = self.tracker.goal
        p = self.robot_position(T)
        reach = self.params.tracker.reach_m
        legs = len(self._waypoints)
        near = [k for k, w in enumerate(self._waypoints) if np.linalg.norm(w[:2] - p[:2]) <= reach]
        if near:  # on from the last turn within reach (the end stays the subgoal)
            del self._waypoints[:min(near[-1] + 1, legs - 1)]
        pts = [p, *self._waypoints]
        d = float(sum(np.linalg.norm(b[:2] - a[:2]) for a, b in itertools.pairwise(pts)))
        if np.linalg.norm(self._waypoints[-1][:2] - p[:2]) <= reach:  # the goal place, or the free cell next to it
            self._finish(out, NavState.REACHED, f"within {reach} m of the goal image's place (past node {node})")
            return out
        nav = NavStatus(NavState.PLANNED, "final approach", node, (node,) if node is not None else (), d)
        self._nav = nav
        self._publish_subgoal(out, nav, force=len(self._waypoints) != legs)
        return out
