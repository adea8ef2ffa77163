"""Why image-goal navigation fails in a changed building (issue #78 item 4), per goal: the same goals
driven with LiteVLoc's localization and with the simulator's true pose in its place, in the building
as mapped or changed (`--change`, as `litevloc sim record --change`). A goal missed with the true pose
as well is the driving's (the local planner, the route), not the localization's.

    .venv/bin/python -m litevloc.experiments.change_nav GENERATOR SEED [--change months_later | AXIS=LEVEL ...]
        [--localization litevloc ground-truth] [--max-goals 6] [--goal-timeout S] [--set KEY=VALUE ...]
        [--json PATH] [--plot PATH]

The map is the building's unchanged one (built once, cached under `--out-dir`); goal images are taken
in the changed building, as `bench/change.py` takes them. Tuning buildings only (never the report
set, `bench/buildings.py`'s default seeds).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path
from typing import Any, Literal

from litevloc.base.params.world_change import ChangeSpecError, WorldChangeParams, parse_change
from litevloc.experiments.buildings import BenchSettings, BuildingRun, building_goals, ensure_map, load_models
from litevloc.experiments.change import changed_world
from litevloc.pipelines.topomap.io import load_map
from litevloc.runtime.tools.sim_navigation import NavRun, plot_navigation, run_navigation

Localization = Literal["litevloc", "ground-truth"]
GOAL_KEYS = ("name", "outcome", "reason", "time_s", "timeout_s", "shortest_path_m", "distance_to_goal_m",
             "placed_node", "placement_error_m")


def goal_rows(run: NavRun) -> list[dict[str, Any]]:
    """Each goal's record of `run`, the keys that say how it ended (`GOAL_KEYS`)."""
    return [{k: g[k] for k in GOAL_KEYS} for g in run.summary()["goals"]]


def navigate(run: BuildingRun, change: WorldChangeParams, modes: list[Localization], max_goals: int,
             goal_timeout_s: float, overrides: tuple[str, ...], out_dir: Path,
             plot: Path | None = None) -> dict[str, Any]:
    """The goals of `run` driven once per localization in `modes` in the building changed by `change`;
    per mode: goals reached, each goal's record, the longest LOST stretch and the fused error."""
    cfg, bundles = load_models("default", overrides)
    bench = BenchSettings(out_dir=out_dir)
    map_dir, _ = ensure_map(run, changed_world(run, WorldChangeParams()), bench, cfg,
                            bundles["build"])  # the benchmarks' map of the building
    world = changed_world(run, change)
    start, goals, _other = building_goals(world, cfg, run.seed, max_goals)
    params = dataclasses.replace(cfg.sim_navigation, goal_timeout_s=goal_timeout_s, vloc_hz=bench.vloc_hz)
    out: dict[str, Any] = {"building": run.name, "change": change.levels(), "start": start, "runs": {}}
    runs = []
    for mode in modes:
        nav = run_navigation(world, cfg, map_dir, goals, world.goal_places[start], mode,
                             params, bundles["nav"])
        runs.append(nav)
        s = nav.summary()
        out["runs"][mode] = {"goals_reached": s["goals_reached"], "goals_total": s["goals_total"],
                             "time_s": s["time_s"], "lost_max_s": s.get("lost_max_s"),
                             "localization_error_m": s.get("localization_error_m"), "goals": goal_rows(nav)}
        print(json.dumps({mode: out["runs"][mode]}), flush=True)
    if plot is not None:
        changed = ", ".join(f"{k} {v:g}" for k, v in change.levels().items() if v) or "unchanged"
        plot_navigation(world, load_map(map_dir), runs, goals, plot, title=f"{run.name}: {changed}")
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("generator")
    ap.add_argument("seed", type=int)
    ap.add_argument("--change", nargs="*", default=[], help="months_later or AXIS=LEVEL items; none: unchanged")
    ap.add_argument("--localization", nargs="+", choices=("litevloc", "ground-truth"),
                    default=["litevloc", "ground-truth"])
    ap.add_argument("--max-goals", type=int, default=6)
    ap.add_argument("--goal-timeout", type=float, default=120.0, metavar="S")
    ap.add_argument("--set", dest="overrides", action="append", default=[])
    ap.add_argument("--out-dir", type=Path, default=Path("out/bench/change_diag"))
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--plot", type=Path, default=None, help="top-down PNG of the drives")
    args = ap.parse_args(argv)
    try:
        change = parse_change(args.change)
    except ChangeSpecError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    out = navigate(BuildingRun(args.generator, args.seed), change, args.localization,
                   args.max_goals, args.goal_timeout, tuple(args.overrides), args.out_dir, args.plot)
    if args.json:
        args.json.write_text(json.dumps(out, default=str))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
