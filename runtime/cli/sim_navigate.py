"""`litevloc sim navigate`: closed-loop image-goal navigation in a simulated world.

    litevloc sim navigate WORLD [--map MAP] [--goals NAME|IMG ...] [--start NAME]
                          [--map-poses ground-truth|slam]
                          [--localization litevloc|ground-truth|both] [--json PATH] [-o PNG]

Without --map the map is built from a simulated mapping pass (`sim record --pass map`,
`map build`), cached under the output folder. Goals are the world's goal places (their
images are rendered like `sim goals`) or image files. With `both` (the default) the run
is repeated with ground-truth localization as the baseline (JSON key `baseline`).
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Literal

from litevloc.base.process_usage import cpu_seconds
from litevloc.runtime.cli.common import add_config_args, config_of, write_json
from litevloc.runtime.cli.main import UserError
from litevloc.runtime.cli.run import add_view_args


def add_parser(ss: argparse._SubParsersAction) -> None:
    n = ss.add_parser("navigate", help="closed loop: sim -> runtime -> planner -> local planner (Zenoh)")
    n.add_argument("world", help="world name (see config/worlds) or YAML file")
    n.add_argument("--map", type=Path, default=None, help="map folder (default: build one, cached)")
    n.add_argument("--goals", nargs="+", default=None,
                   help="goal place names or image files (default: every goal place but --start)")
    n.add_argument("--start", default=None, help="goal place to start at (default: the first)")
    n.add_argument("--map-pass", choices=("map", "map-rooms"), default="map",
                   help="simulated mapping pass when no --map is given: 'map' turns a full circle at each room "
                        "centre, 'map-rooms' also halfway to each end of the room")
    n.add_argument("--map-poses", choices=("ground-truth", "slam"), default="ground-truth",
                   help="when no --map is given: pose the mapping pass with the simulator's ground truth, or with "
                        "the mapping pass's own SLAM on its drifting odometry (map build --poses slam; the map is then "
                        "moved into the world frame by the SE(3) alignment of its keyframes, for the ground-truth "
                        "baseline and the plots; cached in OUT_DIR-slam)")
    n.add_argument("--localization", choices=("litevloc", "ground-truth", "both"), default="both")
    n.add_argument("--vloc-hz", type=float, default=1.0, help="frames to VLoc per simulated second")
    n.add_argument("--goal-timeout", type=float, default=120.0, metavar="S", help="simulated seconds per goal")
    n.add_argument("--seed", type=int, default=0)
    n.add_argument("--world-seed", type=int, default=None,
                   help="generate another building from the world file (what varies: docs/simulator.md)")
    n.add_argument("--goal-camera", choices=("robot", "hand"), default="robot",
                   help="goal images from the robot's camera or the goal rule's hand-held camera")
    n.add_argument("--out-dir", type=Path, default=None,
                   help="folder for the cached map (default: out/navigate/WORLD)")
    n.add_argument("-o", "--output", type=Path, default=None, help="top-down PNG (default: OUT_DIR/navigate.png)")
    n.add_argument("--json", type=Path, default=None, help="results JSON")
    add_view_args(n)  # --view / --view-save: the litevloc run's live view, with the planner's path
    add_config_args(n)
    n.set_defaults(func=run_navigate)


def ensure_map(world_name: str, out_dir: Path, config: str | None, map_duration: float | None = None,
               world_seed: int | None = None, map_pass: str = "map", overrides: Sequence[str] = (),
               map_poses: str = "ground-truth") -> Path:
    """A map of the world from a simulated mapping pass, built once under out_dir.

    The pass is fed to `map build` straight from the simulator (`sim:WORLD?pass=map`):
    depth-only rendering for keyframe selection, colour for the keyframes only, no MCAP
    recording and no JPEG round trip (`sim record` + `map build REC` give the same map
    up to image noise and JPEG artefacts). `overrides`: `KEY=VALUE` config overrides of the
    build (`--set`), e.g. `mapping.keyframes.budget=34`."""
    from urllib.parse import urlencode

    from litevloc.runtime.cli.main import main

    map_dir = out_dir / "map"
    if (map_dir / "manifest.json").is_file():
        return map_dir
    out_dir.mkdir(parents=True, exist_ok=True)
    q: dict[str, str] = {"pass": map_pass, "seed": "0"}
    if map_duration:
        q["duration"] = str(map_duration)
    if world_seed is not None:
        q["world_seed"] = str(world_seed)
    cfg = ["--config", config] if config else []
    sets = [a for kv in overrides for a in ("--set", kv)]
    argv = ["map", "build", f"sim:{world_name}?{urlencode(q)}", "-o", str(map_dir), "--force", *cfg, *sets,
            "--json", str(out_dir / "map.json"), "--poses", map_poses]
    print(f"== litevloc {' '.join(argv)}", flush=True)
    if main(argv) != 0:
        raise UserError(f"building the map failed at: litevloc {' '.join(argv)}")
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

    from litevloc.pipelines.topomap.io import load_map, save_map
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
             view_spawn: bool = False, view_save: Path | None = None, goal_camera: str = "robot") -> dict[str, Any]:
    """Run the loop for each localization mode; returns the results dict (and writes the PNG)."""
    from litevloc.pipelines.topomap.io import load_map
    from litevloc.runtime.sim_navigation import Goal, goal_ratios, plot_navigation, render_goals, run_navigation
    from litevloc.runtime.vloc_models import load_bundle
    from litevloc.sim.world import load_world

    world = load_world(world_name, seed=world_seed)
    places = sorted(world.goal_places)
    if not places:
        raise UserError(f"world {world_name!r} has no goal places")
    start = start or places[0]
    if start not in world.goal_places:
        raise UserError(f"--start {start!r} is not a goal place of {world_name} ({places})")
    names = goal_args or [p for p in places if p != start]  # every other room (office: 5, floor: 14)
    goals: list[Goal] = []
    for g in names:
        if g in world.goal_places:
            camera: Literal["robot", "hand"] = "hand" if goal_camera == "hand" else "robot"
            goals.extend(render_goals(world, cfg, [g], seed=params.seed, camera=camera))
        elif Path(g).is_file():
            goals.append(Goal(Path(g).stem, Path(g).read_bytes(), None))
        else:
            raise UserError(f"goal {g!r} is neither a goal place of {world_name} ({places}) nor an image file")
    bundle = load_bundle(cfg.models)
    runs = {}
    for mode in modes:
        localization: Literal["litevloc", "ground-truth"]
        if mode == "litevloc":
            localization = "litevloc"
        elif mode == "ground-truth":
            localization = "ground-truth"
        else:
            raise UserError(f"unknown localization mode {mode!r}: litevloc or ground-truth")
        print(f"== navigating {len(goals)} goals with {mode} localization", flush=True)
        view = localization == "litevloc"  # the live view shows the runtime: litevloc only
        runs[mode] = run_navigation(world, cfg, map_path, goals, world.goal_places[start], localization, params,
                                    bundle, view_spawn=view_spawn and view, view_save=view_save if view else None)
        s = runs[mode].summary()
        first = "no pose" if s.get("first_pose_s") is None else f"first pose after {s['first_pose_s']:.0f} s"
        moves = f", {s['search_legs']} moves to find it" if s.get("search_legs") else ""
        print(f"   {s['goals_reached']}/{s['goals_total']} reached, {s['time_s']:.0f} s simulated, "
              f"{s['path_length_m']:.1f} m driven ({s['wall_s']:.0f} s wall); {first}{moves}", flush=True)
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


def print_table(res: dict[str, Any]) -> None:
    base = {g["name"]: g for g in res.get("baseline", {}).get("goals", [])}
    head = f"\n{'goal':<12} {'outcome':<9} {'time s':>7} {'path m':>7} {'to goal m':>9}"
    print(head + (f"   {'GT: outcome':<11} {'time s':>7} {'path m':>7}" if base else ""))
    for g in res["goals"]:
        d = g.get("distance_to_goal_m")
        row = (f"{g['name']:<12} {g['outcome']:<9} {g['time_s']:>7.1f} {g['path_length_m']:>7.1f} "
               f"{'' if d is None else f'{d:.2f}':>9}")
        if base:
            b = base.get(g["name"], {})
            row += f"   {b.get('outcome', '-'):<11} {b.get('time_s', 0):>7.1f} {b.get('path_length_m', 0):>7.1f}"
        print(row)
    line = (f"total: {res['goals_reached']}/{res['goals_total']} reached, {res['time_s']:.0f} s, "
            f"{res['path_length_m']:.1f} m")
    if "baseline" in res:
        b = res["baseline"]
        line += (f"; ground truth: {b['goals_reached']}/{b['goals_total']}, {b['time_s']:.0f} s, "
                 f"{b['path_length_m']:.1f} m")
        r = res["ratios"]
        line += (f"; path ratio {r['path_length']:.2f} over the {r['goals_compared']} goal(s) both reached"
                 if r["path_length"] is not None else "; no goal reached by both: no ratio")
    print(line)


def run_navigate(args: argparse.Namespace) -> int:
    from litevloc.runtime.sim_navigation import NavParams

    cfg = config_of(args)
    t0 = time.perf_counter()
    if args.out_dir is None:  # one cached map per world file, world seed and mapping pass
        stem = Path(args.world).stem + ("" if args.world_seed is None else f"-seed{args.world_seed}")
        args.out_dir = Path("out/navigate") / (stem if args.map_pass == "map" else f"{stem}-{args.map_pass}")
        if args.map_poses == "slam":
            args.out_dir = args.out_dir.with_name(args.out_dir.name + "-slam")
    map_path = args.map or ensure_map(args.world, args.out_dir, args.config, world_seed=args.world_seed,
                                      map_pass=args.map_pass, map_poses=args.map_poses)
    modes = ["litevloc", "ground-truth"] if args.localization == "both" else [args.localization]
    try:
        params = NavParams(vloc_hz=args.vloc_hz, goal_timeout_s=args.goal_timeout, seed=args.seed)
    except ValueError as exc:
        raise UserError(str(exc)) from exc
    png = args.output or args.out_dir / "navigate.png"
    res = navigate(args.world, cfg, map_path, args.goals, args.start, modes, params, args.world_seed, png,
                   view_spawn=bool(args.view), view_save=args.view_save, goal_camera=args.goal_camera)
    res["map_info"] = map_summary(map_path)
    for k in ("keyframes", "coverage", "bytes", "build_seconds"):
        res[f"map_{k}"] = res["map_info"][k]
    res["wall_s_total"] = round(time.perf_counter() - t0, 1)
    # CPU seconds of the whole command (all threads): comparable across loads of a shared machine
    res["cpu_s_total"] = round(cpu_seconds(), 1)
    print_table(res)
    print(f"plot: {res.get('png')}")
    write_json(args.json or args.out_dir / "navigate.json", res)
    return 0 if res["goals_reached"] == res["goals_total"] else 1
