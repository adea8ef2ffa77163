"""The planner service (`litevloc plan`): image goals -> subgoals on the map, over Zenoh.

Runs on the planner computer. The algorithms are in `pipelines.navigation.planner`
(goal localization with geometric verification, Dijkstra, `SubgoalTracker`); this module
wires them to messages.

Topics (namespaced like the runtime's, `<ns>/litevloc/...`; CDR ROS 2 payloads):

* in  `litevloc/pose` nav_msgs/Odometry: the fused `T_map_base` from the onboard runtime.
* in  `litevloc/goal_image` sensor_msgs/CompressedImage (JPEG or PNG): a goal; goals are
  queued and visited in order (a sequence). `header.frame_id` names the goal (reported in
  the status). The goal camera is assumed to be the robot's (the map keyframes'
  intrinsics, scaled to the goal image size).
* in  `litevloc/goal_image_raw` sensor_msgs/Image (rgb8, bgr8, rgba8, bgra8, mono8): a goal, as above.
* in  `litevloc/goal_cancel` std_msgs/String: `"current"` skips the active goal (failed,
  reason "cancelled"), `"all"` also empties the queue.
* out `litevloc/subgoal` geometry_msgs/PoseStamped (frame `map`): the base pose at the next
  node of the path (the node keyframe's camera pose moved back to the base, kept level).
* out `litevloc/subgoal_base` geometry_msgs/PoseStamped (frame `base_link`): the same pose
  in the robot frame (`inv(T_map_base) @ T_map_subgoal`), for a local planner.
* out `goal_pose` geometry_msgs/PoseStamped (frame `map`), for Nav2's navigator (`zenoh.goal_pose`):
  "subgoal": each new subgoal (a new path node, or the goal image's place on the final approach);
  "goal": once per goal, the goal image's place (its node's base pose where the map gives no place).
* out `litevloc/planner_status` std_msgs/String, JSON: `state` idle | planned | reached |
  failed, `reason`, `goal` (name), `goal_node`, `subgoal_node`, `path`, `remaining_m`,
  `queued`, `busy` (a goal active or queued), `goals_received`, `seq` (incremented on
  every change), `pose_t_ns` (stamp of the last pose handled). Published on every change and every `status_period_s`.

Ordering contract (what makes closed-loop runs reproducible): poses and goals are handled
in arrival order by one worker thread; for every pose handled while a goal is active or
queued, a subgoal pair or a status stamped with that pose is published (with
`planner.publish_period_s: 0`, the default).

A goal image that matches no map place is reported `failed` with the reason and is never
planned to. Where the map gives the goal image's metric place, the final approach from the
goal node to it is planned on the map's occupancy grid (`pipelines.navigation.approach`)
when the goal arrives; a place the grid cannot reach from its node, or only by a detour
(behind a wall: the placement contradicts the map), is refused with the reason. The goal is
reached only within `tracker.reach_m` of the place.
"""

from __future__ import annotations

import dataclasses
import itertools
import json
import logging
import queue
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from litevloc.base.geometry import invert
from litevloc.config.schema import PlannerConfig, TfConfig
from litevloc.hw import ros_msgs
from litevloc.pipelines.navigation.approach import Approach, plan_approach
from litevloc.pipelines.navigation.candidates import GoalResult
from litevloc.pipelines.navigation.planner import localize_goal
from litevloc.pipelines.navigation.tracker import NavState, NavStatus, SubgoalTracker
from litevloc.pipelines.topomap.types import TopoMap
from litevloc.runtime.metrics import jsonable
from litevloc.runtime.transport.ros_interface import image_to_rgb

log = logging.getLogger(__name__)

KEYS = {
    "pose": "litevloc/pose",
    "goal_image": "litevloc/goal_image",
    "goal_image_raw": "litevloc/goal_image_raw",
    "goal_pose": "goal_pose",
    "goal_cancel": "litevloc/goal_cancel",
    "subgoal": "litevloc/subgoal",
    "subgoal_base": "litevloc/subgoal_base",
    "status": "litevloc/planner_status",
}

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
    t_ns: int
    node: int
    T_map_subgoal: NDArray[np.float64]  # 4x4 base pose at the node, map frame
    T_base_subgoal: NDArray[np.float64]  # 4x4 the same in the robot frame


Output = tuple[str, Any]  # ("status", dict) | ("subgoal", Subgoal)


class GoalPlanner:
    """Message logic of the planner service (no I/O; the service feeds it and publishes).

    Args:
        topomap: the map (node camera poses, connectivity graph).
        locate: goal image (HxWx3 uint8 RGB) -> `GoalResult`.
        params: the `planner` config section.
        T_base_camera: 4x4 camera pose in the base frame (node poses are camera poses).
    """

    def __init__(self, topomap: TopoMap, locate: LocateFn, params: PlannerConfig,
                 T_base_camera: NDArray[np.float64]) -> None:
        self.map, self.locate, self.params = topomap, locate, params
        self.T_base_camera = np.asarray(T_base_camera, np.float64)
        self.T_camera_base = invert(self.T_base_camera)
        # where the base stands at each node: the keyframe camera pose moved back to the base, level
        self.node_base = np.stack([level_pose(T @ self.T_camera_base) for T in topomap.T_map_camera])
        self.tracker = SubgoalTracker(topomap, params.tracker, self.node_base[:, :3, 3])
        # (name, node, inliers, level base pose at the goal image's place or None, its approach from the node)
        self.queue: deque[tuple[str, int, float, NDArray[np.float64] | None, Approach | None]] = deque()
        self.active: str | None = None
        self.goals_received = 0
        self.seq = 0
        self.pose: tuple[int, NDArray[np.float64]] | None = None
        self.status: dict[str, Any] = self._status("idle", "no goal", None)
        self._last_pub_t: int | None = None
        self._last_sub: tuple[int | None, tuple[float, float, float] | None] | None = None  # (node, via)
        self._nav: NavStatus | None = None
        self._goal_base: NDArray[np.float64] | None = None  # metric goal of the active goal (map frame)
        self._final = False  # driving from the goal node to the goal image's own place
        self._approach: Approach | None = None  # the active goal's final approach, planned from its node
        self._waypoints: list[NDArray[np.float64]] = []  # final approach points still to reach (map frame)
        self._progress: tuple[float, int] | None = None  # (closest remaining m, its t_ns) of the active goal

    # ----------------------------------------------------------------- helpers
    def _status(self, state: str, reason: str, goal: str | None, nav: NavStatus | None = None,
                goal_node: int | None = None) -> dict[str, Any]:
        self.seq += 1
        return {
            "state": state, "reason": reason, "goal": goal, "goal_node": goal_node,
            "subgoal_node": None if nav is None else nav.subgoal,
            "path": [] if nav is None else list(nav.path),
            "remaining_m": 0.0 if nav is None else round(float(nav.remaining_m), 3),
            "queued": len(self.queue), "goals_received": self.goals_received, "seq": self.seq,
            "pose_t_ns": None if self.pose is None else self.pose[0],
            "replans": self.tracker.replans, "busy": self.busy,
        }

    def _emit(self, out: list[Output], state: str, reason: str, goal: str | None,
              nav: NavStatus | None = None, goal_node: int | None = None) -> None:
        self.status = self._status(state, reason, goal, nav, goal_node)
        out.append(("status", dict(self.status)))

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
        return Subgoal(t_ns, node, T_map_sub, invert(T_map_base) @ T_map_sub)

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
        return Subgoal(self.pose[0], node, T_goal, invert(self.pose[1]) @ T_goal)

    def place(self, image: NDArray[np.uint8]) -> tuple[GoalResult, NDArray[np.float64] | None, Approach | None]:
        """Where the goal image is (`locate`) and, where the map gives its metric place, the final
        approach to it from its node; a place the approach cannot reach from its node comes back
        refused (`node` None, the approach's reason). Returns (result, level base pose at the
        goal image's place or None, the approach or None)."""
        res = self.locate(image)
        goal_base = None if res.node is None else self.goal_base_pose(res)
        if res.node is None or goal_base is None:
            return res, None, None
        approach = plan_approach(self.map.grid, self.node_base[res.node, :3, 3], goal_base[:3, 3],
                                 self.params.tracker)
        if not approach.ok:
            return dataclasses.replace(res, node=None, reason=f"placed at node {res.node}, refused: "
                                       f"{approach.reason}"), None, None
        return res, goal_base, approach

    @property
    def busy(self) -> bool:
        """A goal is active or queued."""
        return self.active is not None or bool(self.queue)

    # ----------------------------------------------------------------- inputs
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
            res, goal_base, approach = self.place(image)
        except Exception as exc:
            self._emit(out, "failed", f"goal {name!r} rejected: {exc}", name)
            return out
        if res.node is None:
            self._emit(out, "failed", f"goal {name!r}: {res.reason}", name)
            return out
        self.queue.append((name, res.node, float(res.inliers), goal_base, approach))
        where = f"goal {name!r} at node {res.node} ({res.inliers} inliers)"
        if goal_base is not None and approach is not None:
            where += (f", its place {approach.straight_m:.2f} m from the node ({res.pose_inliers} PnP inliers; "
                      f"{approach.length_m:.2f} m on the grid)")
        was_active = self.active
        if self.active is None:
            self._start_next(out)
        if self.active is None and self.pose is None:
            self._emit(out, "idle", f"{where} queued; waiting for a fused pose", None)
        elif was_active is not None:
            self._emit(out, "planned", f"{where} queued behind {was_active!r}", was_active, self._nav,
                       self.tracker.goal)
        return out

    def cancel(self, what: str) -> list[Output]:
        """`current`: fail the active goal and go on; `all`: also drop the queue."""
        out: list[Output] = []
        if what not in ("current", "all"):
            self._emit(out, self.status["state"], f"unknown cancel request {what!r} (current|all)", self.active)
            return out
        if what == "all":
            self.queue.clear()
        if self.active is not None:
            name, self.active, self._final = self.active, None, False
            self._emit(out, "failed", f"goal {name!r} cancelled", name, goal_node=self.tracker.goal)
        self._start_next(out)
        if what == "all" and self.active is None:
            self._emit(out, "idle", "all goals cancelled", None)
        return out

    def _start_next(self, out: list[Output]) -> None:
        while self.active is None and self.queue and self.pose is not None:
            name, node, _, goal_base, approach = self.queue.popleft()
            T = self.pose[1]
            nav = self.tracker.set_goal(node, self.robot_position(T))
            if nav.state == "failed":
                self._emit(out, "failed", f"goal {name!r}: {nav.reason}", name, goal_node=node)
                continue
            self.active, self._nav = name, nav
            self._goal_base, self._approach, self._final, self._progress = goal_base, approach, False, None
            self._waypoints = []
            self._last_sub = None
            self._emit(out, "planned", f"goal {name!r}: {nav.reason}", name, nav, node)
            self._publish_subgoal(out, nav, force=True)

    def _publish_subgoal(self, out: list[Output], nav: NavStatus, force: bool = False) -> None:
        assert self.pose is not None and nav.subgoal is not None
        t_ns, T = self.pose
        period_ns = round(self.params.publish_period_s * 1e9)
        due = (force or self._last_pub_t is None or (nav.subgoal, nav.via) != self._last_sub
               or t_ns - self._last_pub_t >= period_ns)
        if due:
            self._last_pub_t, self._last_sub = t_ns, (nav.subgoal, nav.via)
            out.append(("subgoal", self.subgoal_of(nav.subgoal, t_ns, T, nav.via)))

    def on_pose(self, t_ns: int, T_map_base: NDArray[np.floating]) -> list[Output]:
        """A fused pose: advance / replan / reach; returns what to publish."""
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
        if nav.state == "reached" and self._goal_base is not None:
            node = self.tracker.goal
            assert node is not None and self._approach is not None
            # replanned from where the robot stands (within reach_m of the node); the node's plan otherwise
            here = plan_approach(self.map.grid, self.robot_position(T), self._goal_base[:3, 3], self.params.tracker)
            way = here if here.ok else self._approach
            assert way.waypoints is not None
            self._waypoints = list(way.waypoints)
            self._final, self._progress = True, None  # progress counts on the approach's length now
            self._emit(out, "planned", f"goal {self.active!r}: at node {node}; on to the goal image's place "
                       f"{way.straight_m:.2f} m away ({way.length_m:.2f} m on the grid, {len(self._waypoints)} "
                       "legs)", self.active, nav, node)
            return self._final_approach(out, T)
        if nav.state == "reached":
            name, self.active = self.active, None
            self._emit(out, "reached", f"goal {name!r}: {nav.reason}", name, goal_node=self.tracker.goal)
            self._start_next(out)
        elif nav.state == "failed":
            name, self.active = self.active, None
            self._emit(out, "failed", f"goal {name!r}: {nav.reason}", name, goal_node=self.tracker.goal)
            self._start_next(out)
        else:
            changed = self.tracker.replans != before or nav.subgoal != self.status["subgoal_node"]
            if changed and self._progress is not None and nav.remaining_m > self._progress[0]:
                # a new plan (a replan, or a leg's detour round a wall) made the way longer: progress
                # counts on it from here, or a robot driving the detour is failed as stalled
                self._progress = None
            if changed:
                why = "replanned (strayed from the path)" if self.tracker.replans != before else "next subgoal"
                self._emit(out, "planned", f"goal {self.active!r}: {why}", self.active, nav, self.tracker.goal)
            self._publish_subgoal(out, nav)
        return out


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
        name, self.active, self._final = self.active, None, False
        self._emit(out, "failed", f"goal {name!r}: no progress for {p.stall_s:g} s ({left:.1f} m left, closest "
                   f"{self._progress[0]:.1f} m): blocked?", name, goal_node=self.tracker.goal)
        self._start_next(out)
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
            name, self.active, self._final = self.active, None, False
            self._emit(out, "reached", f"goal {name!r}: within {reach} m of the goal image's place "
                       f"(past node {node})", name, goal_node=node)
            self._start_next(out)
            return out
        nav = NavStatus(NavState.PLANNED, "final approach", node, (node,) if node is not None else (), d)
        self._nav = nav
        self._publish_subgoal(out, nav, force=len(self._waypoints) != legs)
        return out


class PlannerService:
    """`GoalPlanner` on a Zenoh `Bus`: subscriptions feed one worker thread, which publishes.

    Args:
        bus: an open `runtime.transport.bus.Bus` (its namespace prefixes every key; under rmw_zenoh, a ROS node).
        planner: the message logic.
        goal_pose: `zenoh.goal_pose` ("off" | "subgoal" | "goal"): what goes to Nav2 on `goal_pose`.
        tf: the frame ids (`zenoh.tf`).
    """

    def __init__(self, bus: Any, planner: GoalPlanner, goal_pose: str = "off", tf: TfConfig | None = None) -> None:
        self.bus, self.planner = bus, planner
        self.goal_pose = goal_pose
        self.tf = tf or TfConfig()
        self.inbox: queue.Queue[tuple[str, Any]] = queue.Queue()
        self.counters = {"poses_in": 0, "goals_in": 0, "bad_messages": 0, "subgoals_published": 0,
                         "status_published": 0, "goal_poses_published": 0}
        self._stop = threading.Event()
        # (goal, subgoal node, final, approach legs left) last sent to Nav2
        self._last_goal_pose: tuple[str | None, int, bool, int] | None = None
        self._last_goal: str | None = None  # the goal whose place went to Nav2 (goal_pose "goal")
        self.pubs = {
            "subgoal": bus.publisher(KEYS["subgoal"], ros_msgs.POSE_STAMPED),
            "subgoal_base": bus.publisher(KEYS["subgoal_base"], ros_msgs.POSE_STAMPED),
            "status": bus.publisher(KEYS["status"], ros_msgs.STRING, reliable=True),
        }
        if goal_pose != "off":
            self.pubs["goal_pose"] = bus.publisher(KEYS["goal_pose"], ros_msgs.POSE_STAMPED, reliable=True)
        self.subs = [
            bus.subscribe_topic(KEYS["pose"], ros_msgs.ODOMETRY, self._on_pose_sample),
            bus.subscribe_topic(KEYS["goal_image"], ros_msgs.COMPRESSED_IMAGE, self._on_goal_sample),
            bus.subscribe_topic(KEYS["goal_image_raw"], ros_msgs.IMAGE, self._on_raw_goal_sample),
            bus.subscribe_topic(KEYS["goal_cancel"], ros_msgs.STRING, self._on_cancel_sample),
        ]
        self._thread = threading.Thread(target=self._work, name="planner", daemon=True)

    # Zenoh callbacks: decode only, then hand over in arrival order.
    def _on_pose_sample(self, sample: Any) -> None:
        try:
            t_ns, T, _ = ros_msgs.odometry_to_matrix(
                ros_msgs.deserialize(sample.payload.to_bytes(), ros_msgs.ODOMETRY))
        except Exception as exc:
            self.counters["bad_messages"] += 1
            log.warning("bad pose message: %s", exc)
            return
        self.inbox.put(("pose", (t_ns, T)))

    def _on_goal_sample(self, sample: Any) -> None:
        item: tuple[str, bytes | Exception]
        try:
            msg = ros_msgs.deserialize(sample.payload.to_bytes(), ros_msgs.COMPRESSED_IMAGE)
            item = (str(msg.header.frame_id) or f"goal_{self.counters['goals_in']}", bytes(msg.data))
        except Exception as exc:
            item = (f"goal_{self.counters['goals_in']}", exc)
        self.counters["goals_in"] += 1
        self.inbox.put(("goal", item))

    def _on_raw_goal_sample(self, sample: Any) -> None:
        item: tuple[str, NDArray[np.uint8] | Exception]
        try:
            msg = ros_msgs.deserialize(sample.payload.to_bytes(), ros_msgs.IMAGE)
            item = (str(msg.header.frame_id) or f"goal_{self.counters['goals_in']}", image_to_rgb(msg))
        except Exception as exc:
            item = (f"goal_{self.counters['goals_in']}", exc)
        self.counters["goals_in"] += 1
        self.inbox.put(("goal", item))

    def _on_cancel_sample(self, sample: Any) -> None:
        try:
            what = str(ros_msgs.deserialize(sample.payload.to_bytes(), ros_msgs.STRING).data)
        except Exception:
            self.counters["bad_messages"] += 1
            return
        self.inbox.put(("cancel", what))

    # worker
    def start(self) -> PlannerService:
        self._thread.start()
        return self

    def _work(self) -> None:
        period = self.planner.params.status_period_s
        next_status = time.monotonic()
        while not self._stop.is_set():
            try:
                kind, item = self.inbox.get(timeout=max(0.0, min(period, next_status - time.monotonic())))
            except queue.Empty:
                kind, item = "tick", None
            try:
                self.handle(kind, item)
            except Exception:  # a bug must not kill the service silently
                log.exception("planner failed on a %s message", kind)
                self.counters["bad_messages"] += 1
            if time.monotonic() >= next_status and not self._stop.is_set():
                try:
                    self._publish_status(self.planner.status)
                except Exception as exc:  # session closing
                    log.debug("status heartbeat: %s", exc)
                next_status = time.monotonic() + period

    def handle(self, kind: str, item: Any) -> None:
        """Handle one inbox item and publish the outputs (used by the worker, and tests)."""
        p = self.planner
        if kind == "pose":
            self.counters["poses_in"] += 1
            outs = p.on_pose(*item)
        elif kind == "goal":
            name, data = item
            if isinstance(data, Exception):
                p.goals_received += 1
                outs = []
                p._emit(outs, "failed", f"goal {name!r}: undecodable message: {data}", name)
            else:
                outs = p.add_goal(name, data)
        elif kind == "cancel":
            outs = p.cancel(item)
        else:
            return
        for what, payload in outs:
            if what == "status":
                self._publish_status(payload)
            else:
                self._publish_subgoal(payload)
        if self.goal_pose == "goal" and p.active is not None and p.active != self._last_goal:
            place = p.active_goal_place()
            if place is not None:
                self._last_goal = p.active
                self._publish_goal_pose(place)

    def _publish_subgoal(self, s: Subgoal) -> None:
        self.pubs["subgoal"].put(ros_msgs.pose_stamped_msg(s.t_ns, s.T_map_subgoal, self.tf.map_frame))
        self.pubs["subgoal_base"].put(ros_msgs.pose_stamped_msg(s.t_ns, s.T_base_subgoal, self.tf.base_frame))
        self.counters["subgoals_published"] += 1
        if self.goal_pose == "subgoal":  # Nav2 replans on every goal: only a new subgoal is sent
            which = (self.planner.active, s.node, self.planner._final, len(self.planner._waypoints))
            if which != self._last_goal_pose:
                self._last_goal_pose = which
                self._publish_goal_pose(s)

    def _publish_goal_pose(self, s: Subgoal) -> None:
        self.pubs["goal_pose"].put(ros_msgs.pose_stamped_msg(s.t_ns, s.T_map_subgoal, self.tf.map_frame))
        self.counters["goal_poses_published"] += 1

    def _publish_status(self, status: dict[str, Any]) -> None:
        text = json.dumps(jsonable(status), sort_keys=True)
        self.pubs["status"].put(ros_msgs.typestore().types[ros_msgs.STRING](data=text))
        self.counters["status_published"] += 1

    def close(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=5)
        for s in self.subs:
            try:
                s.undeclare()
            except Exception as exc:  # session already closed
                log.debug("undeclare: %s", exc)
        for pub in self.pubs.values():
            pub.undeclare()


def build_planner(cfg: Any, topomap: TopoMap, bundle: Any | None = None) -> GoalPlanner:
    """A `GoalPlanner` from the config (models loaded unless a `ModelBundle` is given)."""
    from litevloc.runtime.vloc_models import check_map_models, load_bundle

    if bundle is None:
        models = dataclasses.replace(cfg.models, intra_op_threads=cfg.runtime.ort_intra_op_threads)
        bundle = load_bundle(models)
    topomap = check_map_models(topomap, bundle)
    locate = goal_locator(topomap, bundle.extract, bundle.describe, bundle.match, cfg.planner)
    return GoalPlanner(topomap, locate, cfg.planner, cfg.fusion.T_base_camera())
