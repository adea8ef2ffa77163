"""`litevloc sim navigate`: closed-loop image-goal navigation in a simulated world.

    litevloc sim navigate WORLD [--map MAP] [--goals NAME|IMG ...] [--start NAME]
                          [--map-poses ground-truth|slam]
                          [--localization litevloc|ground-truth|both] [--json PATH] [-o PNG]

Without --map the map is built from a simulated mapping pass (`sim record --pass map`,
`map build`), cached under the output folder. Goals are the world's goal places (their
images are rendered like `sim goals`) or image files. With `both` (the default) the run
is repeated with ground-truth localization as the baseline (JSON key `baseline`).
The loop's rates, local planner and search come from the config section `sim_navigation`
(`--set sim_navigation.local.max_speed=0.4`); --vloc-hz, --goal-timeout and --seed override it.
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path
from typing import Any

from litevloc.base.process_usage import cpu_seconds
from litevloc.cli.common import add_config_args, config_of
from litevloc.cli.main import UserError
from litevloc.cli.run import add_view_args
from litevloc.runtime.tools.outputs import write_json
from litevloc.runtime.tools.world_navigation import ensure_map, map_summary, navigate


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
    n.add_argument("--concurrent-baseline", action="store_true",
                   help="with --localization both: run the ground-truth baseline in a second process alongside "
                        "the LiteVLoc run (each run's wall time then includes the other's load)")
    n.add_argument("--vloc-hz", type=float, default=None,
                   help="frames to VLoc per simulated second (default: config sim_navigation.vloc_hz)")
    n.add_argument("--goal-timeout", type=float, default=None, metavar="S",
                   help="simulated seconds per goal (default: config sim_navigation.goal_timeout_s)")
    n.add_argument("--seed", type=int, default=None, help="default: config sim_navigation.seed")
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
    flags = {"vloc_hz": args.vloc_hz, "goal_timeout_s": args.goal_timeout, "seed": args.seed}
    try:  # the config's sim_navigation section, with the flags given on top
        params = dataclasses.replace(cfg.sim_navigation, **{k: v for k, v in flags.items() if v is not None})
    except ValueError as exc:
        raise UserError(str(exc)) from exc
    png = args.output or args.out_dir / "navigate.png"
    res = navigate(args.world, cfg, map_path, args.goals, args.start, modes, params, args.world_seed, png,
                   view_spawn=bool(args.view), view_save=args.view_save, goal_camera=args.goal_camera,
                   concurrent_baseline=args.concurrent_baseline)
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
