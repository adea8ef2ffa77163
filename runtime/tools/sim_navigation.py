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
import os
import socket
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import cv2
import numpy as np
from numpy.typing import NDArray

from litevloc.base.figures import save_figure
from litevloc.base.params.sim_navigation import NavParams
from litevloc.config.schema import LiteVLocConfig
from litevloc.hw.messages import Message
from litevloc.pipelines.localization.tracking import TrackingState
from litevloc.pipelines.navigation.candidates import GoalResult
from litevloc.runtime.planner.node import PlannerService, build_planner
from litevloc.runtime.tools.sim_driver import Goal, GoalRecord, NavigationRunError, SimDriver
from litevloc.runtime.transport.bus import Bus, LiteVLocPublisher
from litevloc.sim.realism import sample_lighting
from litevloc.sim.render import Renderer
from litevloc.sim.simulator import Simulator, camera_pose, render_frame
from litevloc.sim.world import World


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


def _zenoh(cfg: LiteVLocConfig, listen: str, connect: tuple[str, ...]) -> Any:
    return dataclasses.replace(cfg.zenoh, mode="peer", listen=(listen,), connect=connect, multicast_scouting=False,
                               require_connect=True, namespace="")


@dataclass
class _Localization:
    """The localization side of the loop: `on_step(step)` after each simulator step -> stamp of
    the pose it published (None: none); `app`: the onboard runtime (litevloc localization only)."""

    on_step: Callable[[Any], int | None]
    app: Any = None
    lost: _LostClock | None = None
    source_box: list[Iterator[Message]] = field(default_factory=list)  # the driver's messages, once it exists


def _litevloc_side(cfg: LiteVLocConfig, z_rt: Any, map_path: Path, view_spawn: bool, view_save: Path | None,
                   closers: list[Callable[[], None]]) -> _Localization:
    """The onboard runtime in sequential mode, reading the driver's simulator messages."""
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

    def on_step(step: Any) -> int | None:
        lost.update(step.t_ns, app.service.core.tracking_state()[0])
        n = app.service.counters["poses_published"]
        if n == last["published"]:
            return None
        last["published"] = n
        return state["t"]

    return _Localization(on_step, app, lost, source_box)


def _ground_truth_side(z_rt: Any, closers: list[Callable[[], None]]) -> _Localization:
    """The simulator's true base pose published on `litevloc/pose` in place of the runtime."""
    gt_bus = Bus(z_rt)
    closers.append(gt_bus.close)
    pub = LiteVLocPublisher(gt_bus)
    closers.append(pub.close)

    def on_step(step: Any) -> int | None:
        pub.publish_pose(step.t_ns, step.T_world_base, np.eye(6) * 1e-4)
        return int(step.t_ns)

    return _Localization(on_step)


def _run_runtime(side: _Localization, gen: Iterator[Message], sim: Simulator, driver: SimDriver) -> dict[str, Any]:
    """Run the onboard runtime over the driver's messages (the whole loop); its figures."""
    app = side.app
    assert app is not None and side.lost is not None
    side.source_box.append(gen)
    res = app.service.run()
    if not res.ok:
        raise NavigationRunError(f"runtime stopped: {res.reason}")
    c = app.service.counters
    return {"runtime": {k: c[k] for k in ("frames_in", "odometry_in", "vloc_calls", "vloc_accepted",
                                          "fusion_accepted", "poses_published")},
            "localization_error_m": _fused_error(app.recorder, sim, driver),
            "lost_max_s": round(side.lost.longest_s, 2), "lost_total_s": round(side.lost.total_s, 2)}


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
                             "vloc_hz": params.vloc_hz, "control_hz": params.control_hz,
                             "pid": os.getpid()}  # the process that drove it (a concurrent baseline's is another)
    placements: list[GoalResult] = []  # each goal image's placement, in the order they arrive
    try:
        side = (_litevloc_side(cfg, z_rt, map_path, view_spawn, view_save, closers) if localization == "litevloc"
                else _ground_truth_side(z_rt, closers))
        pl_bus = Bus(z_pl, node_name=f"{z_pl.node_name}_planner")
        closers.append(pl_bus.close)
        goal_planner = build_planner(cfg, load_map(map_path), bundle, on_placed=lambda pl: placements.append(pl.result))
        planner = PlannerService(pl_bus, goal_planner).start()
        closers.append(planner.close)
        dr_bus = Bus(z_dr, node_name=f"{z_dr.node_name}_sim_driver")
        closers.append(dr_bus.close)
        driver = SimDriver(dr_bus, sim, goals, params, T_bc, side.on_step, color_for_vloc=localization == "litevloc")
        if side.app is not None and side.app.view is not None:
            driver.on_plan = side.app.view.put_plan
        closers.append(driver.close)
        gen = driver.messages(np.asarray(start, np.float64))
        if side.app is not None:
            extra.update(_run_runtime(side, gen, sim, driver))
        else:
            for _ in gen:
                pass
        extra["planner"] = dict(planner.counters)
        extra["replans"] = int(goal_planner.tracker.replans)
        driver.consume_events(sim._t_ns)
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


def placed_position(res: GoalResult, topomap: Any) -> NDArray[np.float64] | None:
    """(3,) where a `GoalResult` put the goal camera (map frame): its metric goal pose, else its
    node's keyframe camera; None when refused."""
    if res.node is None:
        return None
    if res.T_map_goal is not None:
        return np.asarray(res.T_map_goal, np.float64)[:3, 3]
    return np.asarray(topomap.T_map_camera[res.node], np.float64)[:3, 3]


def _placement_records(driver: SimDriver, goals: list[Goal], placements: list[GoalResult], topomap: Any) -> None:
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


def _fused_error(recorder: Any, sim: Simulator, driver: SimDriver) -> dict[str, float]:
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
