"""Closed-loop image-goal navigation in the simulator (`litevloc sim navigate`, the demo).

```
Simulator --odometry, frames--> onboard runtime (runtime.service.app: VLoc + GTSAM fusion)
    --litevloc/pose (Zenoh)--> planner service (runtime.planner.node)
    --litevloc/subgoal_base (Zenoh)--> local planner (sim.local_planner, depth) --(v, omega)--> Simulator
```

Three Zenoh sessions on loopback (free ports): the runtime listens; the planner listens and
connects to it; the robot-side driver (goal sender, subgoal subscriber, local planner)
connects to both. Goal images go to the planner as JPEG `CompressedImage`s, all at once
(a sequence).

Reproducibility: the runtime runs in `sequential` mode (each message handled to
completion in order, no threads), in simulated time as fast as the CPU allows; after each
control step the driver waits until the planner has answered the last published pose
(the planner's ordering contract), so the same seed gives the same run on a loaded machine.
Frames go to VLoc at `vloc_hz` of simulated time (a real robot's VLoc also runs slower
than the camera); every rendered frame's depth feeds the local planner.

`localization="ground-truth"`: the same loop with the fused pose replaced by the
simulator's true base pose (published on `litevloc/pose` in place of the runtime) — the
baseline of the navigation benchmark.

Success of a goal: the planner reported it reached and the true robot position is within
`success_radius_m` of the goal image's true place. Where the planner put each goal image is
recorded as it placed it (`GoalRecord.placed_*`, `placement_error_m` from where the image was
taken).

Goal images: the building's goal places (`litevloc.sim.goals`) seen by the robot's camera
(`camera="robot"`) or by the hand-held camera of the same goal (`camera="hand"`).
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import socket
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import cv2
import numpy as np
from numpy.typing import NDArray

from litevloc.base.errors import LiteVLocError
from litevloc.base.figures import save_figure
from litevloc.base.params.sim_navigation import NavParams
from litevloc.config.schema import LiteVLocConfig
from litevloc.hw import ros_msgs
from litevloc.hw.messages import Message, Odometry
from litevloc.pipelines.localization.tracking import TrackingState
from litevloc.runtime.planner.node import KEYS, PlannerService, build_planner
from litevloc.runtime.transport.bus import Bus, LiteVLocPublisher
from litevloc.sim.local_planner import LocalPlanner
from litevloc.sim.realism import sample_lighting
from litevloc.sim.render import Renderer
from litevloc.sim.search import LocalizationSearch
from litevloc.sim.simulator import Simulator, camera_pose, render_frame
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


@dataclass
class NavRun:
    localization: str
    goals: list[GoalRecord]
    path_xy: NDArray[np.float64]  # (N, 2) true base positions
    subgoals_xy: NDArray[np.float64]  # (M, 2) subgoal positions received (map frame)
    time_s: float
    collisions: int
    wall_s: float
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def path_length_m(self) -> float:
        return float(np.linalg.norm(np.diff(self.path_xy, axis=0), axis=1).sum()) if len(self.path_xy) > 1 else 0.0

    def summary(self) -> dict[str, Any]:
        return {
            "localization": self.localization,
            "goals_total": len(self.goals),
            "goals_reached": sum(g.outcome == "reached" for g in self.goals),
            "time_s": round(self.time_s, 2),
            "path_length_m": round(self.path_length_m, 2),
            "collisions": self.collisions,
            "wall_s": round(self.wall_s, 1),
            "goals": [{k: v for k, v in dataclasses.asdict(g).items() if k != "t_start_ns"} for g in self.goals],
            **self.extra,
        }


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


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def render_goals(world: World, cfg: LiteVLocConfig, names: list[str], seed: int = 0,
                 camera: Literal["robot", "hand"] = "robot") -> list[Goal]:
    """Goal images (JPEG) at the world's goal places as `sim goals` renders them: the robot's
    camera (the robot standing at the goal place) or the goal's hand-held camera (its height and
    tilt drawn by the goal rule; the robot camera's intrinsics and imaging effects)."""
    params = cfg.sim
    ren = Renderer(world)
    light = sample_lighting(params.realism, np.random.default_rng([seed, 11]))
    order = sorted(world.goal_places)
    goals = []
    for name in names:
        if name not in world.goal_places:
            raise ValueError(f"unknown goal place {name!r}; the world has {order}")
        T_base = world.goal_places[name]
        k = order.index(name)
        T_cam = (camera_pose(T_base, 0.0, 0.0, params) if camera == "robot"
                 else world.goal_views[name].T_world_camera_hand)
        f = render_frame(ren, T_cam, params.intrinsics, params.realism, light,
                         np.random.default_rng([seed, 19 if camera == "robot" else 23, k]), 0, k)
        ok, buf = cv2.imencode(".jpg", f.color[:, :, ::-1], [cv2.IMWRITE_JPEG_QUALITY, 90])
        assert ok
        goals.append(Goal(name if camera == "robot" else f"{name}-hand", buf.tobytes(), T_base, T_cam, camera))
    return goals


class _Driver:
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
    def _consume_events(self, t_ns: int) -> None:
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
            self._consume_events(self.sim._t_ns)
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


def _zenoh(cfg: LiteVLocConfig, listen: str, connect: tuple[str, ...]) -> Any:
    return dataclasses.replace(cfg.zenoh, mode="peer", listen=(listen,), connect=connect, multicast_scouting=False,
                               require_connect=True, namespace="")


def run_navigation(
    world: World, cfg: LiteVLocConfig, map_path: Path, goals: list[Goal], start: NDArray[np.float64],
    localization: Literal["litevloc", "ground-truth"] = "litevloc", params: NavParams = NavParams(),
    bundle: Any = None, view_spawn: bool = False, view_save: Path | None = None,
) -> NavRun:
    """One closed-loop run (see the module docstring); `bundle`: models shared with the planner.
    `view_spawn` / `view_save`: the live view of the runtime (litevloc localization only), with
    the planner's path and subgoals."""
    from litevloc.pipelines.topomap.io import load_map
    from litevloc.runtime.vloc_models import load_bundle

    t_wall = time.perf_counter()
    ep = {k: f"tcp/127.0.0.1:{free_port()}" for k in ("runtime", "planner", "driver")}
    z_rt = _zenoh(cfg, ep["runtime"], ())
    z_pl = _zenoh(cfg, ep["planner"], (ep["runtime"],))
    z_dr = _zenoh(cfg, ep["driver"], (ep["runtime"], ep["planner"]))
    T_bc = cfg.fusion.T_base_camera()
    if bundle is None:
        bundle = load_bundle(dataclasses.replace(cfg.models, intra_op_threads=cfg.runtime.ort_intra_op_threads))
    if params.odometry_hz is not None:
        cfg = dataclasses.replace(cfg, sim=dataclasses.replace(cfg.sim, odometry_rate_hz=params.odometry_hz))
    sim = Simulator(world, cfg.sim, seed=params.seed)
    closers: list[Callable[[], None]] = []
    extra: dict[str, Any] = {"mode": "sequential" if localization == "litevloc" else "ground-truth pose",
                             "vloc_hz": params.vloc_hz, "control_hz": params.control_hz}
    try:
        if localization == "litevloc":
            from litevloc.runtime.service.app import build_app

            state: dict[str, int | None] = {"t": None}

            def on_fused(f: Any) -> None:
                if getattr(f, "initialised", True):
                    state["t"] = int(f.t_ns)

            rt_cfg = dataclasses.replace(cfg, zenoh=z_rt, runtime=dataclasses.replace(cfg.runtime, mode="sequential"))
            source_box: list[Iterator[Message]] = []

            class _Source:
                name = "sim-navigate"

                def __iter__(self) -> Iterator[Message]:
                    return source_box[0]

            app = build_app(rt_cfg, map_path, _Source(), 0.0, on_fused=on_fused, view_spawn=view_spawn,
                            view_save=view_save)
            closers.append(app.close)
            last = {"published": 0}
            lost = _LostClock()

            def on_step_rt(step: Any) -> int | None:
                lost.update(step.t_ns, app.service.core.tracking_state()[0])
                n = app.service.counters["poses_published"]
                if n == last["published"]:
                    return None
                last["published"] = n
                return state["t"]

            on_step: Callable[[Any], int | None] = on_step_rt
        else:
            gt_bus = Bus(z_rt)
            closers.append(gt_bus.close)
            pub = LiteVLocPublisher(gt_bus)
            closers.append(pub.close)

            def on_step_gt(step: Any) -> int | None:
                pub.publish_pose(step.t_ns, step.T_world_base, np.eye(6) * 1e-4)
                return int(step.t_ns)

            on_step = on_step_gt

        pl_bus = Bus(z_pl, node_name=f"{z_pl.node_name}_planner")
        closers.append(pl_bus.close)
        goal_planner = build_planner(cfg, load_map(map_path), bundle)
        placements = _record_placements(goal_planner)
        planner = PlannerService(pl_bus, goal_planner).start()
        closers.append(planner.close)
        dr_bus = Bus(z_dr, node_name=f"{z_dr.node_name}_sim_driver")
        closers.append(dr_bus.close)
        driver = _Driver(dr_bus, sim, goals, params, T_bc, on_step, color_for_vloc=localization == "litevloc")
        if localization == "litevloc" and app.view is not None:
            driver.on_plan = app.view.put_plan
        closers.append(driver.close)
        gen = driver.messages(np.asarray(start, np.float64))
        if localization == "litevloc":
            source_box.append(gen)
            res = app.service.run()
            if not res.ok:
                raise NavigationRunError(f"runtime stopped: {res.reason}")
            c = app.service.counters
            extra["runtime"] = {k: c[k] for k in ("frames_in", "odometry_in", "vloc_calls", "vloc_accepted",
                                                   "fusion_accepted", "poses_published")}
            extra["localization_error_m"] = _fused_error(app.recorder, sim, driver)
            extra["lost_max_s"], extra["lost_total_s"] = round(lost.longest_s, 2), round(lost.total_s, 2)
        else:
            for _ in gen:
                pass
        extra["planner"] = dict(planner.counters)
        extra["replans"] = int(planner.planner.tracker.replans)
        driver._consume_events(sim._t_ns)
    finally:
        for close in reversed(closers):
            with contextlib.suppress(Exception):  # best effort on the way out
                close()
    _placement_records(driver, goals, placements, goal_planner.map)
    path = np.array([p[1:] for p in driver.path])
    t_total = (driver.path[-1][0] - driver.path[0][0]) * 1e-9 if driver.path else 0.0
    extra["trace"] = driver.trace
    extra["first_pose_s"] = None if driver.first_pose_s is None else round(driver.first_pose_s, 2)
    extra["search_legs"] = driver.search.legs
    extra["collision_xy"] = driver.collision_xy
    return NavRun(localization, list(driver.records.values()), path, np.array(driver.subgoals_xy).reshape(-1, 2),
                  float(t_total), len(driver.collision_xy), time.perf_counter() - t_wall, extra)


class _LostClock:
    """Longest and total stretch (simulated seconds) the runtime's tracking state was LOST."""

    def __init__(self) -> None:
        self.since_ns: int | None = None
        self.longest_s = self.total_s = 0.0

    def update(self, t_ns: int, state: TrackingState) -> None:
        if state == TrackingState.LOST:
            if self.since_ns is None:
                self.since_ns = t_ns
            self.longest_s = max(self.longest_s, (t_ns - self.since_ns) * 1e-9)
        elif self.since_ns is not None:
            self.total_s += (t_ns - self.since_ns) * 1e-9
            self.since_ns = None


def _record_placements(goal_planner: Any) -> list[Any]:
    """Wrap the planner's goal placement (`GoalPlanner.place`: the locator, then the final
    approach's check) so that each `GoalResult` is kept, in the order the goal images arrive
    (the driver sends them one at a time, each acknowledged)."""
    out: list[Any] = []
    inner = goal_planner.place

    def place(rgb: NDArray[np.uint8]) -> Any:
        res = inner(rgb)
        out.append(res[0])
        return res

    goal_planner.place = place
    return out


def placed_position(res: Any, topomap: Any) -> NDArray[np.float64] | None:
    """(3,) where a `GoalResult` put the goal camera (map frame): its metric goal pose, else its
    node's keyframe camera; None when refused."""
    if res.node is None:
        return None
    if res.T_map_goal is not None:
        return np.asarray(res.T_map_goal, np.float64)[:3, 3]
    return np.asarray(topomap.T_map_camera[res.node], np.float64)[:3, 3]


def _placement_records(driver: _Driver, goals: list[Goal], placements: list[Any], topomap: Any) -> None:
    """Fill each goal record's placement from the locator's results (one per goal, in order)."""
    if len(placements) != len(goals):
        return  # an image the planner could not decode: the order is unknown, leave them unset
    for g, res in zip(goals, placements, strict=True):
        rec = driver.records[g.name]
        p = placed_position(res, topomap)
        rec.placed_node = res.node
        if p is None:
            continue
        rec.placed_xy = (round(float(p[0]), 3), round(float(p[1]), 3))
        if g.T_world_camera is not None:  # the map frame is the world frame (maps built from the simulator)
            rec.placement_error_m = round(float(np.linalg.norm(p[:2] - g.T_world_camera[:2, 3])), 3)


def _fused_error(recorder: Any, sim: Simulator, driver: _Driver) -> dict[str, float]:
    """Median / max horizontal error of the fused base position vs the true one (at step ends)."""
    if not recorder.fused_t:
        return {}
    ft = np.asarray(recorder.fused_t)
    fx = np.array([T[:2, 3] for T in recorder.fused_T])
    errs = []
    for row in driver.path:
        i = int(np.searchsorted(ft, row[0]))
        if i < len(ft) and ft[i] == row[0]:
            errs.append(float(np.linalg.norm(fx[i] - row[1:])))
    if not errs:
        return {}
    return {"median": round(float(np.median(errs)), 3), "max": round(float(np.max(errs)), 3), "n": len(errs)}


def plot_navigation(world: World, topomap: Any, runs: list[NavRun], goals: list[Goal], out_png: Path,
                    title: str = "") -> Path:
    """Top-down PNG: walls, map keyframes and connectivity, driven paths, subgoals, goals."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(10, 7), dpi=110)
    for x0, y0, x1, y1 in world.wall_segments:
        ax.plot([x0, x1], [y0, y1], color="0.3", lw=1.2)
    xy = topomap.positions[:, :2]
    for i, j in topomap.conn_edges:
        ax.plot(xy[[i, j], 0], xy[[i, j], 1], color="tab:green", lw=0.5, alpha=0.35)
    ax.scatter(xy[:, 0], xy[:, 1], s=10, color="tab:green", label=f"map keyframes ({topomap.n_nodes})", zorder=2)
    styles = {"litevloc": ("tab:blue", "-"), "ground-truth": ("tab:orange", "--")}
    for r in runs:
        color, ls = styles.get(r.localization, ("tab:purple", "-"))
        ax.plot(r.path_xy[:, 0], r.path_xy[:, 1], color=color, ls=ls, lw=1.6,
                label=f"driven, {r.localization} localization ({r.path_length_m:.1f} m)")
        if len(r.subgoals_xy):
            ax.scatter(r.subgoals_xy[:, 0], r.subgoals_xy[:, 1], s=14, marker="x", color=color, zorder=3)
    if runs and len(runs[0].path_xy):
        x0, y0 = runs[0].path_xy[0]
        ax.scatter([x0], [y0], s=80, marker="o", facecolor="none", edgecolor="k", label="start", zorder=4)
    for k, g in enumerate(goals):
        if g.T_world_base is None:
            continue
        x, y = g.T_world_base[:2, 3]
        ax.scatter([x], [y], s=160, marker="*", color="tab:red", zorder=5, label="goal places" if k == 0 else None)
        ax.annotate(f"{k + 1}: {g.name}", (x, y), textcoords="offset points", xytext=(6, 6), fontsize=8)
    ax.scatter([], [], marker="x", color="0.4", label="subgoals (x)")
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(title or "LiteVLoc image-goal navigation")
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8)
    return save_figure(fig, out_png)


def goal_ratios(goals: list[dict[str, Any]], base_goals: list[dict[str, Any]]) -> dict[str, Any]:
    """LiteVLoc / ground-truth time and path over the goals both reached (None when there is
    none: a run that reached nothing has no meaningful ratio), and how many goals that is."""
    base = {g["name"]: g for g in base_goals}
    both = [(g, base[g["name"]]) for g in goals
            if g["outcome"] == "reached" and base.get(g["name"], {}).get("outcome") == "reached"]
    out: dict[str, Any] = {"goals_compared": len(both), "path_length": None, "time": None}
    if both:
        for key, field in (("path_length", "path_length_m"), ("time", "time_s")):
            den = sum(b[field] for _, b in both)
            out[key] = round(sum(g[field] for g, _ in both) / den, 3) if den > 0 else None
    return out
