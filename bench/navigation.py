"""Image-goal navigation benchmark (like the paper's navigation table), in the simulator.

    .venv/bin/python bench/navigation.py [--worlds office floor bland] [--map-pass map|map-rooms]
                                         [--maps-dir out/bench/nav_maps]

Per world: the map is built once from a simulated mapping pass (cached under
--maps-dir), then a sequence of five goal images (the world's goal places after the start
place) is driven twice in the closed loop of `litevloc sim navigate`: with LiteVLoc
localization (runtime in sequential mode, VLoc at 1 Hz of simulated time, GTSAM fusion,
poses and subgoals over Zenoh on loopback) and with ground-truth localization (the
baseline, measured in the same run). Reported per goal: success, simulated time to the
goal, path length; per world: totals and LiteVLoc / ground-truth ratios over the goals both reached.

`bland` is the texture-poor, repetitive test world (issue #15 item 6). `--map-pass map-rooms`
maps with a full circle also halfway to each end of every room (results keyed WORLD-map-rooms).

Writes out/bench/navigation.json and prints a table.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import OUT, print_table, write_json

from litevloc.config import load_config
from litevloc.runtime.tools.world_navigation import ensure_map, navigate


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--worlds", nargs="+", default=["office", "floor", "bland"])
    ap.add_argument("--map-pass", choices=["map", "map-rooms"], default="map",
                    help="simulated mapping pass: 'map-rooms' also turns halfway to each end of every room")
    ap.add_argument("--maps-dir", type=Path, default=OUT / "nav_maps")
    ap.add_argument("--goal-timeout", type=float, default=120.0)
    ap.add_argument("--vloc-hz", type=float, default=1.0)
    args = ap.parse_args(argv)
    cfg = load_config("default")
    results = {}
    rows = []
    for world in args.worlds:
        name = world if args.map_pass == "map" else f"{world}-{args.map_pass}"
        t0 = time.perf_counter()
        try:
            map_path = ensure_map(world, args.maps_dir / name, "default", map_pass=args.map_pass)
            t_map = time.perf_counter() - t0
            res = navigate(world, cfg, map_path, None, None, ["litevloc", "ground-truth"],
                           dataclasses.replace(cfg.sim_navigation, goal_timeout_s=args.goal_timeout,
                                               vloc_hz=args.vloc_hz),
                           png=OUT / f"navigation_{name}.png")
        except Exception as exc:  # report and go on with the next world
            results[name] = {"error": f"{type(exc).__name__}: {exc}", "wall_s": time.perf_counter() - t0}
            rows.append([name, "error", "", "", "", "", "", str(exc)[:60]])
            continue
        res["map_wall_s"] = round(t_map, 1)
        results[name] = res
        base = {g["name"]: g for g in res["baseline"]["goals"]}
        for g in res["goals"]:
            b = base[g["name"]]
            rows.append([name, g["name"], g["outcome"], round(g["time_s"], 1), round(g["path_length_m"], 1),
                         b["outcome"], round(b["time_s"], 1), round(b["path_length_m"], 1)])
        b = res["baseline"]
        rows.append([name, "TOTAL", f"{res['goals_reached']}/{res['goals_total']}", res["time_s"],
                     res["path_length_m"], f"{b['goals_reached']}/{b['goals_total']}", b["time_s"],
                     b["path_length_m"]])
        rows.append([name, "first pose s (moves to find it)", "n/a" if res.get("first_pose_s") is None else
                     f"{res['first_pose_s']} ({res.get('search_legs', 0)})", "", "", "", "", ""])
        r = res["ratios"]
        rows.append([name, f"ratio LiteVLoc/GT ({r['goals_compared']} both reached)", "",
                     "n/a" if r["time"] is None else r["time"], "n/a" if r["path_length"] is None else r["path_length"],
                     "", "", ""])
        _save(results)  # after each world: a long world cannot lose the others' results
    print_table("Image-goal navigation (simulated time; GT = ground-truth localization baseline)",
                ["world", "goal", "LiteVLoc", "time s", "path m", "GT", "time s", "path m"], rows)
    _save(results)
    return 0


def _save(results: dict) -> None:
    """Write out/bench/navigation.json, keeping other worlds' results from an earlier run."""
    import json

    path = OUT / "navigation.json"
    worlds = {}
    if path.is_file():
        try:
            worlds = json.loads(path.read_text()).get("worlds", {})
        except ValueError:
            worlds = {}
    write_json("navigation", {"worlds": {**worlds, **results}})


if __name__ == "__main__":
    raise SystemExit(main())
