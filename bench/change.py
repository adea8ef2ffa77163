"""A map that stays useful as the building changes (issue #78): localization and navigation in
buildings that changed since they were mapped, before and after one `map update`.

    python bench/change.py [--generators office floor bland] [--seeds 10:17] [--buildings N]
        [--levels AXIS=L1,L2 ...] [--no-mix] [--cycles 10] [--quick] [--no-nav] [--json PATH]
    python bench/change.py --merge A.json B.json ... [--json PATH]

Per building (generators x seeds; the default is the buildings report set, 10:17 of every
generator; `--buildings N` keeps the first N): the map of the building as generated, then for
every axis and level (default `experiments.change.LEVELS`) and the `months_later` mix (fixed
in advance in `litevloc.base.params.world_change.MIXES`: lighting 0.5, 30 % of the furniture
changed, 30 % of the pictures replaced, two people in view) GL from no prior on the changed
building's query pass, image-goal navigation in it, then the same after one update run through
it; and `--cycles` updates in a row through a building that keeps changing
(`experiments.change`). `--quick`: every 45th query frame, every 10th session frame, two
goals, two cycles (a development run, not the report).

`--json PATH` writes `cases` (per axis and level: `gl_accepted_of_covered`, `wrong_over_0_5m`,
`gl_accepted_of_covered_unchanged`, `goals_reached`, `goals_total`, `goals_reached_unchanged`,
and `after_update` with the same keys), `update_cycles` (`cycle`, `map_size_ratio` to the map
before any update, `map_size_ratio_to_first_update`, `gl_accepted_of_covered`) and `buildings`
(every per-frame and per-goal record). A plot of the figures against the level per axis goes
beside it (PATH with .png).

`--merge` pools the buildings of runs made apart (one process per core: buildings run one after
another, each model on one thread) into one JSON, as one run over all of them would write it; the
runs must share their settings but the buildings.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import OUT, print_table, run_meta
from buildings import parse_seeds

from litevloc.base.params.world_change import CHANGE_AXES
from litevloc.experiments.buildings import GENERATORS, BenchSettings, BuildingRun, load_models
from litevloc.experiments.change import LEVELS, MONTHS_LATER, Case, ChangeSettings, contract, plot, run_building


def parse_levels(items: list[str]) -> dict[str, tuple[float, ...]]:
    """`["furniture=0.3,0.6", "people=2"]` -> {axis: levels}; argparse error on a bad item."""
    out: dict[str, tuple[float, ...]] = {}
    for item in items:
        axis, _, raw = item.partition("=")
        if axis not in CHANGE_AXES or not raw:
            raise argparse.ArgumentTypeError(f"--levels {item!r}: want AXIS=L1,L2 with AXIS in {list(CHANGE_AXES)}")
        try:
            out[axis] = tuple(float(v) for v in raw.split(","))
        except ValueError as exc:
            raise argparse.ArgumentTypeError(f"--levels {item!r}: levels must be numbers") from exc
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--generators", nargs="+", default=list(GENERATORS), help="world names or YAML files")
    ap.add_argument("--seeds", type=parse_seeds, default=range(10, 17))
    ap.add_argument("--buildings", type=int, default=None, help="the first N buildings only")
    ap.add_argument("--levels", action="append", default=[], metavar="AXIS=L1,L2",
                    help="levels of an axis (repeatable); given: only the axes named")
    ap.add_argument("--no-mix", action="store_true", help="leave out the months_later mix")
    ap.add_argument("--mix-only", action="store_true", help="the months_later mix alone (no per-axis cases)")
    ap.add_argument("--cycles", type=int, default=None)
    ap.add_argument("--max-goals", type=int, default=None)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--no-nav", action="store_true", help="GL figures only (goal fields null)")
    ap.add_argument("--query-every", type=int, default=None, help="every Nth query frame (default 15; quick 45)")
    ap.add_argument("--session-every", type=int, default=None, help="every Nth frame of an update run (default 5; "
                    "quick 10)")
    ap.add_argument("--query-duration", type=float, default=None, help="the query pass's first S seconds only")
    ap.add_argument("--session-duration", type=float, default=None,
                    help="an update run's first S seconds only (default: the whole mapping pass)")
    ap.add_argument("--out-dir", type=Path, default=OUT / "change")
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--json", type=Path, default=OUT / "change.json")
    ap.add_argument("--merge", type=Path, nargs="+", default=None, metavar="RUN_JSON",
                    help="pool these runs' buildings (same settings) instead of running")
    args = ap.parse_args(argv)
    if args.merge:
        try:
            return write_result(*merged(args.merge), args.json)
        except (OSError, ValueError, KeyError) as exc:
            print(f"change: --merge: {exc}", file=sys.stderr)
            return 2
    try:
        levels = parse_levels(args.levels) if args.levels else dict(LEVELS)
    except argparse.ArgumentTypeError as exc:
        ap.error(str(exc))
    cases = [] if args.mix_only else [Case(a, lv) for a, lvs in levels.items() for lv in lvs]
    cases += [] if args.no_mix else [Case(MONTHS_LATER, 1.0)]
    runs = [BuildingRun(g, s) for s in args.seeds for g in args.generators][: args.buildings]
    max_goals = args.max_goals if args.max_goals is not None else (2 if args.quick else 6)
    settings = ChangeSettings(
        buildings=BenchSettings(out_dir=args.out_dir, max_goals=max_goals,
                                goal_timeout_s=60.0 if args.quick else 120.0),
        query_every=args.query_every or (45 if args.quick else 15), query_duration_s=args.query_duration,
        session_every=args.session_every or (10 if args.quick else 5), session_duration_s=args.session_duration,
        cycles=args.cycles if args.cycles is not None else (2 if args.quick else 10), navigate=not args.no_nav)
    cfg, bundles = load_models("default", tuple(args.overrides))
    buildings = []
    for run in runs:
        print(f"[{run.name}] {len(cases)} cases, {settings.cycles} update cycles ...", flush=True)
        buildings.append(run_building(run, cases, settings, cfg, bundles))
    run_settings = {"runs": [r.name for r in runs], "cases": [dataclasses.asdict(c) for c in cases],
                    "query_every": settings.query_every, "session_every": settings.session_every,
                    "session_duration_s": settings.session_duration_s,
                    "cycles": settings.cycles, "max_goals": max_goals, "navigate": settings.navigate,
                    "overrides": args.overrides}
    return write_result({"meta": run_meta(), "settings": run_settings}, buildings, args.json)


def merged(paths: list[Path]) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """(meta and settings, buildings) of the runs `paths` (their JSON) pooled; ValueError where
    their settings differ but for the buildings, or a building comes twice."""
    runs = [json.loads(p.read_text()) for p in paths]
    head = {k: v for k, v in runs[0]["settings"].items() if k != "runs"}
    for p, r in zip(paths[1:], runs[1:], strict=True):
        other = {k: v for k, v in r["settings"].items() if k != "runs"}
        if other != head:
            diff = sorted(k for k in head.keys() | other.keys() if head.get(k) != other.get(k))
            raise ValueError(f"{p} was run with other settings than {paths[0]} ({', '.join(diff)})")
    buildings = [b for r in runs for b in r["buildings"]]
    names = [b["building"] for b in buildings]
    if len(set(names)) < len(names):
        raise ValueError(f"a building comes twice: {names}")
    metas = [r["meta"] for r in runs]
    # the busiest run's load and the last run's end: what the pooled figures were measured under
    meta = {**run_meta(), "time": max(m["time"] for m in metas), "load_avg": max(m["load_avg"] for m in metas),
            "merged": [{"json": str(p), **m} for p, m in zip(paths, metas, strict=True)]}
    return {"meta": meta, "settings": {**head, "runs": names}}, buildings


def write_result(head: dict[str, Any], buildings: list[dict[str, Any]], path: Path) -> int:
    """Print the tables of `buildings` (`contract`), write them with `head` (meta, settings) to
    `path` and the plot beside it; the exit status."""
    result = contract(buildings)
    cols = ["axis", "level", "GL acc/cov", "unchanged", "wrong", "goals", "unchanged goals", "GL after upd",
            "goals after upd"]
    rows = [[c["axis"], c["level"], c["gl_accepted_of_covered"], c["gl_accepted_of_covered_unchanged"],
             c["wrong_over_0_5m"], f"{c['goals_reached']}/{c['goals_total']}", c["goals_reached_unchanged"],
             c["after_update"]["gl_accepted_of_covered"],
             f"{c['after_update']['goals_reached']}/{c['after_update']['goals_total']}"] for c in result["cases"]]
    print_table(f"Change benchmark, {len(buildings)} buildings (GL from no prior; wrong: accepted > 0.5 m off)",
                cols, rows)
    if result["update_cycles"]:
        print_table("Update cycles (months-later building, a new change seed each cycle)",
                    ["cycle", "map size ratio", "to the first update", "GL acc/cov"],
                    [[c["cycle"], c["map_size_ratio"], c["map_size_ratio_to_first_update"], c["gl_accepted_of_covered"]]
                     for c in result["update_cycles"]])
    path.parent.mkdir(parents=True, exist_ok=True)
    payload = {**head, **result, "buildings": buildings}
    path.write_text(json.dumps(payload, indent=1, default=float) + "\n")
    if not result["cases"] and not result["update_cycles"]:
        print(f"wrote {path}")
        return 0
    png = plot(result, path.with_suffix(".png"))
    print(f"wrote {path} and {png}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
