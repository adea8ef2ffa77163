"""The robot side of the closed-loop simulator run (`runtime.tools.sim_navigation`): it sends
the goal images, follows the planner's subgoals with the local planner (depth) and steps the
simulator, recording how each goal went (`GoalRecord`).

Reproducibility: after each control step it waits until the planner has answered the last
published pose (the planner's ordering contract), so the same seed gives the same run on a
loaded machine.
"""

from __future__ import annotations

import contextlib
import json
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from litevloc.base.errors import LiteVLocError
from litevloc.base.params.sim_navigation import NavParams
from litevloc.hw import ros_msgs
from litevloc.hw.messages import Message, Odometry
from litevloc.runtime.planner.node import KEYS
from litevloc.runtime.transport.bus import Bus
from litevloc.sim.local_planner import LocalPlanner
from litevloc.sim.search import LocalizationSearch
from litevloc.sim.simulator import Simulator
from litevloc.sim.trajectory import PlanningError, plan_path
from litevloc.sim.world import World


class NavigationRunError(LiteVLocError, RuntimeError):
    """The closed loop could not run (planner unreachable, no answer in time)."""


@dataclass(frozen=True)
class Goal:
    name: str
    jpeg: bytes
    T_world_base: NDArray[np.float64] | None  # true place (None: unknown, e.g. a user image)
    T_world_camera: NDArray[np.float64] | None = None  # where the image was taken (4x4; None: unknown)
    camera: str = "robot"  # "robot" | "hand" (a hand-held camera) | "file"


@dataclass
class GoalRecord:
    name: str
    outcome: str = "pending"  # reached | failed | timeout | pending
    reason: str = ""
    planner_reached: bool = False
    goal_node: int | None = None
    time_s: float = 0.0  # simulated seconds from when this goal became active
    path_length_m: float = 0.0
    distance_to_goal_m: float | None = None  # true, at the end
    camera: str = "robot"
    placed_node: int | None = None  # where the planner put the goal image (None: refused)
    placed_xy: tuple[float, float] | None = None  # its metric goal pose, else its node's camera (map = world frame)
    placement_error_m: float | None = None  # horizontal, from where the image was taken (None: unknown)
    shortest_path_m: float | None = None  # free-space path from where the goal became active to its place
    timeout_s: float | None = None  # this goal's budget (see NavParams.goal_timeout_s_per_m)
    t_start_ns: int | None = None


def goal_budget(world: World, start_xy: NDArray[np.floating], goal_xy: NDArray[np.floating], robot_radius: float,
                params: NavParams) -> tuple[float, float | None]:
    """A goal's time budget (simulated s) and its shortest free path (m; None where none is found)
    from the robot's true position `start_xy` to the goal's place `goal_xy` (world frame, m):
    `goal_timeout_s`, or `goal_timeout_s_per_m` x that path where longer (a far room of a large
    floor needs more time than a near one)."""
    if params.goal_timeout_s_per_m <= 0:
        return params.goal_timeout_s, None
    try:
        path = plan_path(world, np.asarray(start_xy, np.float64), np.asarray(goal_xy, np.float64), robot_radius)
    except PlanningError:  # no free path (a place within furniture's clearance): the base budget
        return params.goal_timeout_s, None
    length = round(float(np.linalg.norm(np.diff(path, axis=0), axis=1).sum()), 2)
    return max(params.goal_timeout_s, params.goal_timeout_s_per_m * length), length


class SimDriver:
    """Robot side of the loop: goal sender, subgoal/status subscriber, local planner, simulator."""

    def __init__(self, bus: Bus, sim: Simulator, goals: list[Goal], params: NavParams,
                 T_base_camera: NDArray[np.float64], on_step: Callable[[Any], int | None],
                 color_for_vloc: bool = True) -> None:
        self.bus, self.sim, self.params = bus, sim, params
        # colour is rendered only for the steps whose frame goes to VLoc; the local planner
        # reads depth alone (ground-truth runs never render colour)
        self.color_for_vloc = color_for_vloc
        self.goals = goals
        self.T_base_camera = T_base_camera
        self.on_step = on_step  # after a step's messages were handled: -> stamp of the last published pose
        self.local = LocalPlanner(params.local)
        self.search = LocalizationSearch(self.local, params.search)
        self.first_pose_s: float | None = None  # sensor time from the start to the first fused pose
        self.cond = threading.Condition()
        self.sub_t = -1
        self.sub_T: NDArray[np.float64] | None = None
        self.status: dict[str, Any] = {}
        self.events: list[dict[str, Any]] = []
        self.on_plan: Callable[[dict[str, Any]], None] | None = None  # the live view's put_plan, if on
        self.subgoals_xy: list[tuple[float, float]] = []
        self.records = {g.name: GoalRecord(g.name, camera=g.camera) for g in goals}
        self.path: list[NDArray[np.float64]] = []
        self.collision_xy: list[tuple[float, float]] = []  # true base position at each bump (metres)
        self.last_depth: NDArray[np.float32] | None = None
        self.trace: list[tuple[Any, ...]] = []
        self.T_odom_base: NDArray[np.float64] | None = None
        self.K = sim.K.K
        self.pose_seen = False
        self.goals_sent = False
        self.subs = [
            bus.subscribe_topic(KEYS["subgoal_base"], ros_msgs.POSE_STAMPED, self._on_sub),
            bus.subscribe_topic(KEYS["subgoal"], ros_msgs.POSE_STAMPED, self._on_sub_map),
            bus.subscribe_topic(KEYS["status"], ros_msgs.STRING, self._on_status),
        ]
        self.goal_pub = bus.publisher(KEYS["goal_image"], ros_msgs.COMPRESSED_IMAGE, reliable=True)
        self.cancel_pub = bus.publisher(KEYS["goal_cancel"], ros_msgs.STRING, reliable=True)

    # ------------------------------------------------------------ callbacks
    def _on_sub(self, sample: Any) -> None:
        msg = ros_msgs.deserialize(sample.payload.to_bytes(), ros_msgs.POSE_STAMPED)
        with self.cond:
            self.sub_t = ros_msgs.stamp_ns(msg.header)
            self.sub_T = ros_msgs.pose_to_matrix(msg.pose)
            self.cond.notify_all()

    def _on_sub_map(self, sample: Any) -> None:
        msg = ros_msgs.deserialize(sample.payload.to_bytes(), ros_msgs.POSE_STAMPED)
        xy = (round(float(msg.pose.position.x), 3), round(float(msg.pose.position.y), 3))
        with self.cond:
            if not self.subgoals_xy or self.subgoals_xy[-1] != xy:
                self.subgoals_xy.append(xy)

    def _on_status(self, sample: Any) -> None:
        st = json.loads(ros_msgs.deserialize(sample.payload.to_bytes(), ros_msgs.STRING).data)
        with self.cond:
            if not self.status or st["seq"] > self.status["seq"]:
                self.events.append(st)
            if not self.status or st["seq"] >= self.status["seq"]:
                self.status = st
            self.cond.notify_all()
        if self.on_plan is not None:
            self.on_plan(st)

    def _wait(self, pred: Callable[[], bool], what: str, timeout: float | None = None) -> None:
        with self.cond:
            if not self.cond.wait_for(pred, timeout or self.params.answer_timeout_s):
                raise NavigationRunError(f"no answer from the planner service: {what} "
                                         f"(last status {self.status or 'none'})")

    # --------------------------------------------------------------- helpers
    def consume_events(self, t_ns: int) -> None:
        with self.cond:
            events, self.events = self.events, []
        for st in events:
            name = st.get("goal")
            rec = self.records.get(name) if name else None
            if rec is None:
                continue
            if st["state"] == "planned" and rec.t_start_ns is None:
                rec.t_start_ns = int(st["pose_t_ns"] if st["pose_t_ns"] is not None else t_ns)
                rec.goal_node = st.get("goal_node")
                goal = next(g for g in self.goals if g.name == name)
                if goal.T_world_base is not None:
                    rec.timeout_s, rec.shortest_path_m = goal_budget(
                        self.sim.world, self.sim.T_world_base[:2, 3], goal.T_world_base[:2, 3],
                        self.sim.params.robot_radius, self.params)
            elif st["state"] in ("reached", "failed") and rec.outcome == "pending":
                rec.planner_reached = st["state"] == "reached"
                rec.outcome = "reached" if rec.planner_reached else ("timeout" if "cancelled" in st["reason"]
                                                                     and rec.reason == "timeout" else "failed")
                rec.reason = st["reason"] if rec.reason != "timeout" else f"timeout: {st['reason']}"
                rec.goal_node = st.get("goal_node", rec.goal_node)
                end = int(st["pose_t_ns"] if st["pose_t_ns"] is not None else t_ns)
                if rec.t_start_ns is not None:
                    rec.time_s = (end - rec.t_start_ns) * 1e-9
                    rec.path_length_m = self._path_since(rec.t_start_ns, end)
                g = next(g for g in self.goals if g.name == name)
                if g.T_world_base is not None:
                    d = float(np.linalg.norm(self.sim.T_world_base[:2, 3] - g.T_world_base[:2, 3]))
                    rec.distance_to_goal_m = round(d, 3)
                    if rec.planner_reached and d > self.params.success_radius_m:
                        rec.outcome = "failed"
                        rec.reason += f"; but {d:.2f} m from the true goal place (> {self.params.success_radius_m})"

    def _bumper(self, T_world_base: NDArray[np.float64]) -> None:
        """A simulated bumper: points of a ring just outside the robot that lie on a wall or
        box (within 3 cm of one) become contact obstacles of the local planner."""
        r = self.sim.params.robot_radius + 0.02
        ang = np.linspace(-np.pi, np.pi, 36, endpoint=False)
        ring_base = np.stack([r * np.cos(ang), r * np.sin(ang)], 1)
        T = np.asarray(T_world_base, np.float64)
        ring_world = ring_base @ T[:2, :2].T + T[:2, 3]
        touch = self.sim.world.clearance(ring_world) < 0.03
        if touch.any():
            assert self.T_odom_base is not None
            self.local.add_contacts(ring_base[touch], self.T_odom_base)

    def _path_since(self, t0: int, t1: int) -> float:
        pts = [p[1:] for p in self.path if t0 <= p[0] <= t1]
        return float(np.linalg.norm(np.diff(np.array(pts), axis=0), axis=1).sum()) if len(pts) > 1 else 0.0

    def _pending(self) -> list[GoalRecord]:
        return [r for r in self.records.values() if r.outcome == "pending"]

    def _command(self, t_ns: int, t0_ns: int) -> tuple[float, float]:
        with self.cond:
            busy = self.status.get("state") == "planned"
            T = self.sub_T if busy else None
        if T is None:
            if not self.pose_seen and (t_ns - t0_ns) * 1e-9 > self.params.search_after_s:
                if self.T_odom_base is None:
                    return 0.0, self.params.search.omega  # no odometry yet: look around
                c = self.search.command(t_ns * 1e-9, self.T_odom_base, self.last_depth, self.K, self.T_base_camera)
                self.trace.append((t_ns * 1e-9, *self.sim.T_world_base[:2, 3].round(2), None, None,
                                   round(c.v, 2), round(c.omega, 2), c.reason))
                return c.v, c.omega
            return 0.0, 0.0
        c = self.local.command(T[:2, 3], self.last_depth, self.K, self.T_base_camera, self.T_odom_base)
        self.trace.append((t_ns * 1e-9, *self.sim.T_world_base[:2, 3].round(2), round(float(T[0, 3]), 2),
                           round(float(T[1, 3]), 2), round(c.v, 2), round(c.omega, 2), c.reason))
        return c.v, c.omega

    # ------------------------------------------------------------------ loop
    def messages(self, start: NDArray[np.float64]) -> Iterator[Message]:
        """Simulator messages for the runtime; drives the whole loop while being consumed."""
        p = self.params
        step = self.sim.reset(start)
        t0 = step.t_ns
        yield from step.odometry
        if step.frame is not None:
            self.last_depth = step.frame.depth
            yield step.frame
        self._after(step)
        # Zenoh declarations propagate asynchronously: wait for the planner to be heard.
        self._wait(lambda: bool(self.status), "no planner status within the timeout")
        # a goal put before the planner's subscription has reached this session would be dropped
        if not self.goal_pub.wait_for_subscribers(p.answer_timeout_s):
            raise NavigationRunError("the planner service never subscribed to goal images")
        # one goal at a time, each acknowledged before the next (a burst of images is what a
        # congested transport would have to queue); the error names the goal that got no answer
        base = self.status.get("goals_received", 0)
        for k, g in enumerate(self.goals):
            self.goal_pub.put(ros_msgs.compressed_image_msg(step.t_ns, g.jpeg, "jpeg", g.name))
            self._wait(lambda k=k: self.status.get("goals_received", 0) >= base + k + 1,  # type: ignore[misc]
                       f"goal image {g.name!r} ({k + 1} of {len(self.goals)}) not acknowledged",
                       timeout=max(p.answer_timeout_s, 60.0))  # model inference, loaded CPUs
        self.goals_sent = True
        dt = 1.0 / p.control_hz
        vloc_every = max(1, round(p.control_hz / p.vloc_hz))
        k = 0
        while True:
            self.consume_events(self.sim._t_ns)
            if not self._pending():
                return
            active = next((r for r in self._pending() if r.t_start_ns is not None), None)
            if active is not None and active.t_start_ns is not None and active.reason != "timeout" and \
                    (self.sim._t_ns - active.t_start_ns) * 1e-9 > (active.timeout_s or p.goal_timeout_s):
                active.reason = "timeout"
                self.cancel_pub.put(ros_msgs.typestore().types[ros_msgs.STRING](data="current"))
                self._wait(lambda a=active: any(e.get("goal") == a.name and e["state"] == "failed"  # type: ignore[misc]
                                                for e in self.events), f"cancel of {active.name}")
                continue
            if all(r.t_start_ns is None for r in self._pending()) and self.pose_seen and \
                    (self.sim._t_ns - t0) * 1e-9 > p.goal_timeout_s * len(self.goals):
                for r in self._pending():
                    r.outcome, r.reason = "failed", "never planned (no pose / no path)"
                return
            if not self.pose_seen and (self.sim._t_ns - t0) * 1e-9 > p.goal_timeout_s:
                # no fused pose at all after looking around for a goal's time: nothing can be
                # planned, and a run that waits for one would never end
                for r in self._pending():
                    r.outcome = "failed"
                    r.reason = (f"never localized: no pose within {p.goal_timeout_s:g} s of looking around "
                                f"({self.search.legs} moves to open space)")
                return
            v, w = self._command(self.sim._t_ns, t0)
            k += 1
            to_vloc = self.color_for_vloc and k % vloc_every == 0
            step = self.sim.step(v, w, dt, color=to_vloc)
            msgs: list[Message] = list(step.odometry)
            if step.depth is not None:
                self.last_depth = step.depth
            if step.frame is not None and to_vloc:
                msgs.append(step.frame)
            msgs.sort(key=lambda m: (m.t_ns, isinstance(m, Odometry)))
            yield from msgs
            self._after(step)

    def _after(self, step: Any) -> None:
        if step.collided:
            x, y = step.T_world_base[:2, 3]
            self.collision_xy.append((round(float(x), 2), round(float(y), 2)))
        if step.collided and self.T_odom_base is not None:
            self._bumper(step.T_world_base)
        if step.odometry:
            self.T_odom_base = step.odometry[-1].T_odom_base
        self.path.append(np.array([step.t_ns, *step.T_world_base[:2, 3]]))
        pose_t = self.on_step(step)
        if pose_t is None:
            return
        if not self.pose_seen and self.path:
            self.first_pose_s = (step.t_ns - self.path[0][0]) * 1e-9
        self.pose_seen = True

        n_sent = len(self.goals)

        def answered() -> bool:
            # the planner answers every pose while busy; once it says it is idle (after all our
            # goals were received) it answers nothing until we send goals again
            st = self.status
            if self.sub_t >= pose_t:
                return True
            return bool(st) and not st.get("busy", True) and st.get("goals_received", 0) >= n_sent

        with self.cond:
            busy = not self.status or self.status.get("busy", True)
        if busy and self.goals_sent and self._pending():
            self._wait(answered, f"answer to the pose at t={pose_t * 1e-9:.2f} s")

    def close(self) -> None:
        for s in self.subs:
            with contextlib.suppress(Exception):  # session closed
                s.undeclare()
        self.goal_pub.undeclare()
        self.cancel_pub.undeclare()
