"""The planner service (`litevloc plan`): image goals -> subgoals on the map, over Zenoh.

Runs on the planner computer. The node only subscribes and publishes: the goal queue and its
states are the core's (`runtime.planner.core.GoalPlanner`), the algorithms `pipelines.navigation`'s
(goal placement with geometric verification, Dijkstra, `SubgoalTracker`).

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
import json
import logging
import queue
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from litevloc.config.schema import TfConfig
from litevloc.hw import ros_msgs
from litevloc.pipelines.topomap.types import TopoMap
from litevloc.runtime.metrics import jsonable
from litevloc.runtime.planner.core import GoalPlanner, Placement, PlannerStatus, Subgoal, goal_locator
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
            outs = p.reject_goal(name, str(data)) if isinstance(data, Exception) else p.add_goal(name, data)
        elif kind == "cancel":
            outs = p.cancel(item)
        else:
            return
        for out in outs:
            if isinstance(out, PlannerStatus):
                self._publish_status(out)
            else:
                self._publish_subgoal(out)
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
            which = (s.goal, s.node, s.final, s.legs_left)
            if which != self._last_goal_pose:
                self._last_goal_pose = which
                self._publish_goal_pose(s)

    def _publish_goal_pose(self, s: Subgoal) -> None:
        self.pubs["goal_pose"].put(ros_msgs.pose_stamped_msg(s.t_ns, s.T_map_subgoal, self.tf.map_frame))
        self.counters["goal_poses_published"] += 1

    def _publish_status(self, status: PlannerStatus) -> None:
        text = json.dumps(jsonable(status.as_dict()), sort_keys=True)
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


def build_planner(cfg: Any, topomap: TopoMap, bundle: Any | None = None,
                  on_placed: Callable[[Placement], None] | None = None) -> GoalPlanner:
    """A `GoalPlanner` from the config (models loaded unless a `ModelBundle` is given;
    `on_placed`: see `GoalPlanner`)."""
    from litevloc.runtime.vloc_models import check_map_models, load_bundle

    if bundle is None:
        models = dataclasses.replace(cfg.models, intra_op_threads=cfg.runtime.ort_intra_op_threads)
        bundle = load_bundle(models)
    topomap = check_map_models(topomap, bundle)
    locate = goal_locator(topomap, bundle.extract, bundle.describe, bundle.match, cfg.planner)
    return GoalPlanner(topomap, locate, cfg.planner, cfg.fusion.T_base_camera(), on_placed)
