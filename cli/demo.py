"""`litevloc demo`: the main job on the embedded default (a simulated office, no data needed).

1. record a mapping pass through the world (`sim record --pass map`),
2. build the map-lite map from it (`map build`),
3. navigate to a sequence of goal images in closed loop (`sim navigate`): simulator ->
   onboard runtime (VLoc + GTSAM fusion, fused pose published over Zenoh on loopback) ->
   planner service (goal localization with geometric verification, Dijkstra, subgoals
   over Zenoh) -> depth-based local planner -> simulator; alongside it, in a second process,
   the same with ground-truth localization as the baseline,
4. print a results table (per goal: outcome, time, path length; fused-pose error) and write
   a top-down PNG (map, driven paths, subgoals, goals) and a JSON summary.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

from litevloc.cli.common import add_json_arg
from litevloc.cli.main import UserError
from litevloc.runtime.tools.outputs import write_json

# The demo's mapping pass at 5 Hz: the map build takes a keyframe candidate every 0.3 m or 12 deg
# (2 frames while turning at 0.6 rad/s, 3 while driving at 0.5 m/s), so the map keeps its coverage
# while recording, building and the MCAP shrink about threefold (`--full`: the camera's 15 Hz).
DEMO_MAP_CAMERA_HZ = 5.0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="the main job: map the simulated office, then navigate to goal images")
    p.add_argument("--world", default="office", help="simulated world (default: office)")
    p.add_argument("-o", "--output", type=Path, default=Path("out/demo"), help="output folder")
    p.add_argument("--map-duration", type=float, default=None, metavar="S",
                   help="seconds of the mapping pass (default: the whole pass)")
    p.add_argument("--map-camera-hz", type=float, default=DEMO_MAP_CAMERA_HZ, metavar="HZ",
                   help=f"camera rate of the recorded mapping pass (default: {DEMO_MAP_CAMERA_HZ:g}; the same route "
                        "and keyframe thresholds, a third of the frames to render, store and read)")
    p.add_argument("--full", action="store_true",
                   help="the full-length run: the mapping pass recorded at the simulator's camera rate "
                        "(sim.camera_rate_hz) instead of --map-camera-hz")
    p.add_argument("--reuse-map", action="store_true", help="keep OUTPUT/map if it exists")
    p.add_argument("--goals", nargs="+", default=None, help="goal places (default: five after the start)")
    p.add_argument("--no-baseline", action="store_true", help="skip the ground-truth-localization run")
    p.add_argument("--config", default="default", help="preset or YAML (default: default)")
    add_json_arg(p)
    p.set_defaults(func=run)


def _step(title: str, argv: list[str]) -> float:
    from litevloc.cli.main import main

    print(f"\n== {title}: litevloc {' '.join(argv)}", flush=True)
    t0 = time.perf_counter()
    rc = main(argv)
    if rc not in (0, 1) or (rc == 1 and argv[:2] != ["sim", "navigate"]):
        raise UserError(f"demo step '{title}' failed with exit code {rc}")
    return time.perf_counter() - t0


def run(args: argparse.Namespace) -> int:
    out: Path = args.output
    out.mkdir(parents=True, exist_ok=True)
    cfg = ["--config", args.config]
    times: dict[str, float] = {}
    map_rec, map_dir = out / "map.mcap", out / "map"
    if not (args.reuse_map and (map_dir / "manifest.json").is_file()):
        dur = ["--duration", str(args.map_duration)] if args.map_duration else []
        rate = [] if args.full else ["--set", f"sim.camera_rate_hz={args.map_camera_hz:g}"]
        times["record_map_pass"] = _step("record the mapping pass", [
            "sim", "record", args.world, "--pass", "map", "--seed", "0", "-o", str(map_rec), *dur, *cfg, *rate,
            "--json", str(out / "record_map.json")])
        times["build_map"] = _step("build the map", [
            "map", "build", str(map_rec), "-o", str(map_dir), "--force", *cfg, "--json", str(out / "map.json")])
    nav_json, png = out / "navigate.json", out / "demo.png"
    goals = ["--goals", *args.goals] if args.goals else []
    # the baseline drives alongside: the LiteVLoc run leaves most of a second core idle
    loc = ["--localization", "litevloc"] if args.no_baseline else ["--localization", "both", "--concurrent-baseline"]
    times["navigate"] = _step("navigate to goal images (LiteVLoc localization; ground truth as baseline, alongside)", [
        "sim", "navigate", args.world, "--map", str(map_dir), *goals, *loc, "--out-dir", str(out), "-o", str(png),
        "--json", str(nav_json), *cfg])
    nav: dict[str, Any] = json.loads(nav_json.read_text())
    summary: dict[str, Any] = {"world": args.world, "seconds": {k: round(v, 1) for k, v in times.items()},
                               "navigation": nav, "png": str(png)}
    if (out / "map.json").is_file():
        summary["map"] = json.loads((out / "map.json").read_text())
    rows = result_rows(nav)
    rows.append(("wall time", ", ".join(f"{k} {v:.0f} s" for k, v in times.items())))
    rows.append(("plot", str(png)))
    print("\n== LiteVLoc demo results")
    for k, v in rows:
        print(f"{k:<26} {v}")
    ok = nav["goals_reached"] == nav["goals_total"]
    summary["ok"] = ok
    write_json(args.json or out / "demo.json", summary)
    return 0 if ok else 1


def result_rows(nav: dict[str, Any]) -> list[tuple[str, str]]:
    """The results table's rows of a `sim navigate --json` summary (goals, baseline, ratios,
    fused error, VLoc); a run where no goal was reached by both modes has no ratio."""
    rows = [("goals reached (LiteVLoc)", f"{nav['goals_reached']}/{nav['goals_total']} in {nav['time_s']:.0f} s "
                                         f"simulated, {nav['path_length_m']:.1f} m driven, "
                                         f"{nav['collisions']} collisions")]
    if "baseline" in nav:
        b = nav["baseline"]
        rows.append(("ground-truth baseline", f"{b['goals_reached']}/{b['goals_total']} in {b['time_s']:.0f} s, "
                                              f"{b['path_length_m']:.1f} m"))
        r = nav.get("ratios") or {}
        rows.append(("LiteVLoc / baseline", "no goal reached by both: no ratio" if r.get("path_length") is None
                     else f"path x{r['path_length']:.2f}, time x{r['time']:.2f}"))
    err = nav.get("localization_error_m") or {}
    if err:
        rows.append(("fused pose error", f"median {100 * err['median']:.1f} cm, max {100 * err['max']:.1f} cm "
                                         f"(base position vs ground truth, {err['n']} control steps)"))
    rt = nav.get("runtime") or {}
    if rt:
        rows.append(("VLoc", f"{rt['vloc_calls']} queries, {rt['vloc_accepted']} accepted, "
                             f"{rt['poses_published']} fused poses published over Zenoh"))
    return rows
