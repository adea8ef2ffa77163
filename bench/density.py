"""Navigation against keyframe density (issue #15 item 5): sparse maps degrade gracefully.

    .venv/bin/python bench/density.py [--world office] [--fractions 1.0 0.5 0.25]

The world's mapping pass is built once with the defaults (the coverage target decides the
keyframe count N), then again with the keyframe budget capped at each fraction of N
(`--set mapping.keyframes.budget=round(f * N)`, the same pass and seed; maps cached under
out/bench/density/WORLD/). Each map then drives the world's goal sequence twice in the closed
loop of `litevloc sim navigate`: with LiteVLoc localization and with ground-truth localization
(the baseline, same map, same run). Reported per map and goal: outcome, the planner's reason
when a goal is refused or fails, simulated time to that outcome, path length; per map: goals
reached, the slowest failure (the acceptance: a goal the map cannot place ends `failed` within
30 s of simulated time) and the path ratio against the baseline (<= 2x: the robot never
wanders).

Writes out/bench/density.json and prints a table.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import OUT, print_table, write_json

from litevloc.config import load_config
from litevloc.runtime.tools.world_navigation import ensure_map, navigate


def keyframes_of(map_dir: Path) -> int:
    """Keyframe count of a built map (its manifest)."""
    return int(json.loads((map_dir / "manifest.json").read_text())["nodes"])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--world", default="office")
    ap.add_argument("--fractions", nargs="+", type=float, default=[1.0, 0.5, 0.25])
    ap.add_argument("--maps-dir", type=Path, default=OUT / "density")
    ap.add_argument("--goal-timeout", type=float, default=120.0)
    args = ap.parse_args(argv)
    if any(not 0 < f <= 1 for f in args.fractions):
        raise SystemExit("--fractions must lie in (0, 1]")
    cfg = load_config("default")
    full = ensure_map(args.world, args.maps_dir / args.world / "full", "default")
    n_full = keyframes_of(full)
    results: dict[str, Any] = {"world": args.world, "keyframes_full": n_full, "maps": []}
    rows: list[list[Any]] = []
    for f in args.fractions:
        budget = max(2, round(f * n_full))
        t0 = time.perf_counter()
        map_dir = full if f == 1.0 else ensure_map(
            args.world, args.maps_dir / args.world / f"budget_{budget}", "default",
            overrides=[f"mapping.keyframes.budget={budget}"])
        t_map = time.perf_counter() - t0
        build = json.loads((map_dir.parent / "map.json").read_text())
        res = navigate(args.world, cfg, map_dir, None, None, ["litevloc", "ground-truth"],
                       dataclasses.replace(cfg.sim_navigation, goal_timeout_s=args.goal_timeout),
                       png=OUT / f"density_{args.world}_{budget}.png")
        base = res["baseline"]
        failed = [g for g in res["goals"] if g["outcome"] != "reached"]
        entry = {
            "fraction": f, "keyframes": keyframes_of(map_dir), "coverage": build.get("coverage"),
            "map_wall_s": round(t_map, 1), "goals_total": res["goals_total"],
            "goals_reached": res["goals_reached"], "baseline_goals_reached": base["goals_reached"],
            "path_length_m": res["path_length_m"], "baseline_path_length_m": base["path_length_m"],
            "path_ratio": res["ratios"]["path_length"], "collisions": res["collisions"],
            "slowest_failure_s": max((g["time_s"] for g in failed), default=0.0),
            "goals": res["goals"], "baseline_goals": base["goals"], "png": res.get("png"),
        }
        results["maps"].append(entry)
        for g, b in zip(res["goals"], base["goals"], strict=True):
            rows.append([f, entry["keyframes"], g["name"], g["outcome"], round(g["time_s"], 1),
                         round(g["path_length_m"], 1), b["outcome"], g["reason"][:70]])
        rows.append([f, entry["keyframes"], "TOTAL", f"{entry['goals_reached']}/{entry['goals_total']}",
                     res["time_s"], res["path_length_m"], f"{base['goals_reached']}/{base['goals_total']}",
                     f"path x{entry['path_ratio']}, slowest failure {entry['slowest_failure_s']:.1f} s"])
        write_json("density", results)  # after each map: a later failure keeps the earlier ones
    print_table(f"Navigation against keyframe density, {args.world} (simulated time; GT = ground-truth "
                "localization on the same map)",
                ["fraction", "keyframes", "goal", "LiteVLoc", "time s", "path m", "GT", "reason / note"], rows)
    write_json("density", results)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
