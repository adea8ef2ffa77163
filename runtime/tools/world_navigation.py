"""Image-goal navigation in a simulated world, end to end: the world's map (built once from a
simulated mapping pass, cached), its goal images, one run per localization mode and the results
(what `litevloc sim navigate` and the navigation benchmarks run)."""

from __future__ import annotations

import contextlib
import multiprocessing
from collections.abc import Sequence
from concurrent.futures import Future, ProcessPoolExecutor
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

from litevloc.base.errors import LiteVLocError
from litevloc.runtime.tools.map_building import MapBuildRequest, build_map
from litevloc.runtime.tools.outputs import write_json

if TYPE_CHECKING:
    from litevloc.runtime.tools.sim_driver import Goal
    from litevloc.runtime.tools.sim_navigation import NavRun


class NavigationSetupError(LiteVLocError, ValueError):
    """The world, start or goals asked for do not exist (names the one that is wrong)."""


def ensure_map(world_name: str, out_dir: Path, config: str | None, map_duration: float | None = None,
               world_seed: int | None = None, map_pass: str = "map", overrides: Sequence[str] = (),
               map_poses: str = "ground-truth") -> Path:
    """A map of the world from a simulated mapping pass, built once under out_dir.

    The pass is built straight from the simulator (`sim:WORLD?pass=map`):
    depth-only rendering for keyframe selection, colour for the keyframes only, no MCAP
    recording and no JPEG round trip (`sim record` + `map build REC` give the same map
    up to image noise and JPEG artefacts). `overrides`: `KEY=VALUE` config overrides of the
    build (as `--set`), e.g. `mapping.keyframes.budget=34`."""
    from urllib.parse import urlencode

    from litevloc.config import load_config

    map_dir = out_dir / "map"
    if (map_dir / "manifest.json").is_file():
        return map_dir
    out_dir.mkdir(parents=True, exist_ok=True)
    q: dict[str, str] = {"pass": map_pass, "seed": "0"}
    if map_duration:
        q["duration"] = str(map_duration)
    if world_seed is not None:
        q["world_seed"] = str(world_seed)
    req = MapBuildRequest(src=f"sim:{world_name}?{urlencode(q)}", output=map_dir, force=True, poses=map_poses,
                          config=config)
    print(f"== map build {req.src} -> {map_dir} (--config {config} {' '.join(overrides)}; poses {map_poses})",
          flush=True)
    write_json(out_dir / "map.json", build_map(req, load_config(config, list(overrides))))
    if map_poses == "slam":
        _to_world_frame(map_dir, out_dir / "map.json")
    return map_dir


def _to_world_frame(map_dir: Path, report: Path) -> None:
    """Move a SLAM map (frame: its first keyframe) into the simulated world's frame by the SE(3)
    alignment of its keyframes to the ground truth that `map build` reported after the build:
    a rigid move, so the map's shape stays the SLAM's; the ground-truth baseline publishes world
    poses and success is judged in the world."""
    import json
    import shutil

    import numpy as np

    from litevloc.pipelines.topomap.io import load_map
    from litevloc.pipelines.topomap.map_save import save_map
    from litevloc.pipelines.topomap.merge import transform_map

    ev = json.loads(report.read_text())["slam"]["evaluation"]
    T = np.asarray(ev["T_reference_map"], np.float64)
    moved = map_dir.with_name(map_dir.name + ".world")  # the loaded map reads its files lazily: write aside
    save_map(transform_map(load_map(map_dir), T), moved, overwrite=True)
    shutil.rmtree(map_dir)
    moved.rename(map_dir)


def map_summary(map_path: Path) -> dict[str, Any]:
    """The map's keyframes, coverage, bytes and build seconds (from its manifest)."""
    from litevloc.pipelines.topomap.io import load_map, storage_summary

    m = load_map(map_path)
    st = storage_summary(map_path)

    def num(key: str) -> float | None:
        v = m.meta.get(key)
        try:
            return float(v) if v not in (None, "None") else None
        except ValueError:
            return None

    return {"keyframes": m.n_nodes, "coverage": num("keyframe_coverage"), "bytes": int(sum(st.values())),
        "build_seconds": num("build_seconds"), "budget": m.meta.get("keyframe_budget"),
        "budget_bound": m.meta.get("keyframe_budget_bound") == "True", "storage": st}


def navigate(world_name: str, cfg: Any, map_path: Path, goal_args: list[str] | None, start: str | None,
             modes: list[str], params: Any, world_seed: int | None = None, png: Path | None = None,
             view_spawn: bool = False, view_save: Path | None = None, goal_camera: str = "robot",
             concurrent_baseline: bool = False) -> dict[str, Any]:
    """Run the loop for each localization mode; returns the results dict (and writes the PNG).
    `concurrent_baseline`: the ground-truth run goes to a second process alongside the others
    (each run's wall time then includes the other's load). That process is spawned, so a script
    calling this with it must do so under `if __name__ == "__main__":` (multiprocessing's rule)."""
    from litevloc.pipelines.topomap.io import load_map
    from litevloc.runtime.tools.sim_driver import Goal
    from litevloc.runtime.tools.sim_navigation import goal_ratios, plot_navigation, render_goals, run_navigation
    from litevloc.runtime.vloc_models import load_bundle
    from litevloc.sim.world import load_world

    world = load_world(world_name, seed=world_seed)
    places = sorted(world.goal_places)
    if not places:
        raise NavigationSetupError(f"world {world_name!r} has no goal places")
    start = start or places[0]
    if start not in world.goal_places:
        raise NavigationSetupError(f"--start {start!r} is not a goal place of {world_name} ({places})")
    names = goal_args or [p for p in places if p != start]  # every other room (office: 5, floor: 14)
    goals: list[Goal] = []
    for g in names:
        if g in world.goal_places:
            camera: Literal["robot", "hand"] = "hand" if goal_camera == "hand" else "robot"
            goals.extend(render_goals(world, cfg, [g], seed=params.seed, camera=camera))
        elif Path(g).is_file():
            goals.append(Goal(Path(g).stem, Path(g).read_bytes(), None))
        else:
            raise NavigationSetupError(f"goal {g!r} is neither a goal place of {world_name} ({places}) "
                                       "nor an image file")
    for mode in modes:
        if mode not in ("litevloc", "ground-truth"):
            raise NavigationSetupError(f"unknown localization mode {mode!r}: litevloc or ground-truth")
    aside = concurrent_baseline and "ground-truth" in modes and len(modes) > 1
    runs: dict[str, NavRun] = {}
    with contextlib.ExitStack() as stack:
        baseline: Future[NavRun] | None = None
        if aside:  # spawned before this process loads models: the child loads its own
            pool = stack.enter_context(ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")))
            print(f"== navigating {len(goals)} goals with ground-truth localization (in a second process)",
                  flush=True)
            baseline = pool.submit(_ground_truth_run, world_name, world_seed, cfg, map_path, goals, start, params)
        bundle = load_bundle(cfg.models)
        for mode in modes:
            if aside and mode == "ground-truth":
                continue
            localization: Literal["litevloc", "ground-truth"] = "litevloc" if mode == "litevloc" else "ground-truth"
            print(f"== navigating {len(goals)} goals with {mode} localization", flush=True)
            view = localization == "litevloc"  # the live view shows the runtime: litevloc only
            runs[mode] = run_navigation(world, cfg, map_path, goals, world.goal_places[start], localization, params,
                                        bundle, view_spawn=view_spawn and view, view_save=view_save if view else None)
            _print_run(mode, runs[mode])
        if baseline is not None:
            runs["ground-truth"] = baseline.result()
            _print_run("ground-truth", runs["ground-truth"])
    runs = {m: runs[m] for m in modes}
    main_mode = modes[0]
    out: dict[str, Any] = {"world": world_name, "start": start, "goals": [g.name for g in goals],
                           "map": str(map_path)}
    res = runs[main_mode].summary()
    res.pop("trace", None)
    out.update(res)
    if "ground-truth" in runs and main_mode != "ground-truth":
        base = runs["ground-truth"].summary()
        base.pop("trace", None)
        out["baseline"] = base
        out["ratios"] = goal_ratios(res["goals"], base["goals"])
    if png is not None:
        out["png"] = str(plot_navigation(world, load_map(map_path), list(runs.values()), goals, png,
                                         f"LiteVLoc image-goal navigation: {world_name}"))
    out["per_goal_time_s"] = [g["time_s"] for g in res["goals"]]
    return out


def _print_run(mode: str, run: NavRun) -> None:
    s = run.summary()
    first = "no pose" if s.get("first_pose_s") is None else f"first pose after {s['first_pose_s']:.0f} s"
    moves = f", {s['search_legs']} moves to find it" if s.get("search_legs") else ""
    print(f"   {mode}: {s['goals_reached']}/{s['goals_total']} reached, {s['time_s']:.0f} s simulated, "
          f"{s['path_length_m']:.1f} m driven ({s['wall_s']:.0f} s wall); {first}{moves}", flush=True)


def _ground_truth_run(world_name: str, world_seed: int | None, cfg: Any, map_path: Path, goals: list[Goal],
                      start: str, params: Any) -> NavRun:
    """The ground-truth baseline in a process of its own (`navigate(concurrent_baseline=True)`)."""
    from litevloc.runtime.tools.sim_navigation import run_navigation
    from litevloc.runtime.vloc_models import load_bundle
    from litevloc.sim.world import load_world

    world = load_world(world_name, seed=world_seed)
    return run_navigation(world, cfg, map_path, goals, world.goal_places[start], "ground-truth", params,
                          load_bundle(cfg.models))
