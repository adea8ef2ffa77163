"""Image-goal navigation in many generated buildings (issue 42): map each, then drive its goal
images with LiteVLoc and with ground-truth localization (`litevloc.experiments.buildings`).

    .venv/bin/python bench/buildings.py [--seeds 10:17] [--generators office floor bland]
                                        [--appearance aliased] [--workers 2] [--name buildings]

`--seeds A:B` selects world seeds A..B-1 of every generator (the default, 10:17, is the
report set: 21 buildings; seeds 100-102 are the tuning set). `--appearance aliased` runs the
same buildings with the first simulator's pictures (results named BUILDING-aliased).
Maps are kept under out/bench/buildings/BUILDING/map and reused by a later run unless
`--fresh-maps`. Prints a table per building and the totals, writes out/bench/NAME.json
(keys: `buildings[*]` with `map`, `litevloc`, `ground-truth`, `other_set`, `figures`;
`totals` with the acceptance checks) and out/bench/NAME.png; each building's record is also appended to
out/bench/NAME.partial.jsonl as it finishes, so a run stopped early keeps what it did.
`--combine A.json B.partial.jsonl ...` runs nothing: it reports the buildings of earlier runs
together (a report set run in parts), each with its own run's record.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import OUT, print_table, run_meta, write_json

from litevloc.config import load_config
from litevloc.experiments.buildings import GENERATORS, BenchSettings, BuildingRun, render_cost, run_buildings
from litevloc.experiments.buildings_report import building_figures, placement_totals, plot, table_rows, totals

HEADER = ["building", "keyframes", "free %", "openings", "LiteVLoc", "GT", "refused", "wrong", "collisions LV/GT",
          "first fix s", "lost max s", "path ratio", "wall s"]


def parse_seeds(text: str) -> range:
    """`A:B` -> range(A, B); `A` -> range(A, A + 1)."""
    try:
        a, _, b = text.partition(":")
        return range(int(a), int(b) if b else int(a) + 1)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"--seeds must look like A:B, got {text!r}") from exc


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=parse_seeds, default=range(10, 17))
    ap.add_argument("--generators", nargs="+", default=list(GENERATORS))
    ap.add_argument("--appearance", choices=["varied", "aliased"], default=None)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--goal-timeout", type=float, default=120.0)
    ap.add_argument("--max-goals", type=int, default=6, help="goal rooms per building at most (drawn with the seed)")
    ap.add_argument("--fresh-maps", action="store_true", help="rebuild every map")
    ap.add_argument("--name", default="buildings", help="results in out/bench/NAME.json and NAME.png")
    ap.add_argument("--json", type=Path, default=None, help="write the results here instead")
    ap.add_argument("--out-dir", type=Path, default=OUT / "buildings")
    ap.add_argument("--placement-only", action="store_true",
                    help="place every room's robot and hand-held goal image (no driving), under the defaults and "
                         "each --alt-set variant")
    ap.add_argument("--alt-set", action="append", default=[], metavar="KEY=VALUE[,KEY=VALUE]",
                    help="a configuration variant for --placement-only (repeat for more)")
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                    help="a configuration override for every run (repeat for more)")
    ap.add_argument("--render-frames", type=int, default=40,
                    help="frames per building of the rendering-cost comparison (first simulator's buildings vs these, "
                         "the first seed of each generator; 0: skip)")
    ap.add_argument("--combine", type=Path, nargs="+", default=None, metavar="FILE",
                    help="no run: report the buildings of earlier runs together (their NAME.json or "
                         "NAME.partial.jsonl; each building keeps its own run's record)")
    args = ap.parse_args(argv)
    if args.combine:
        return _combined_report(args)
    runs = [BuildingRun(g, s, args.appearance) for s in args.seeds for g in args.generators]
    variants = (("defaults", ()), *((v, tuple(v.split(","))) for v in args.alt_set)) if args.placement_only else ()
    settings = BenchSettings(goal_timeout_s=args.goal_timeout, out_dir=args.out_dir, keep_maps=not args.fresh_maps,
                             max_goals=args.max_goals, placement_variants=variants,
                             overrides=tuple(args.overrides))
    render = render_cost([BuildingRun(g, args.seeds.start) for g in args.generators], load_config("default"),
                         args.render_frames) if args.render_frames else []
    if render:
        print_table("Rendering cost per frame (the same seeds; frames in turn)", list(render[0]),
                    [list(r.values()) for r in render])
    t0 = time.perf_counter()
    print(f"{len(runs)} buildings, {args.workers} workers", flush=True)

    partial = (OUT / args.name if args.json is None else args.json).with_suffix(".partial.jsonl")
    partial.parent.mkdir(parents=True, exist_ok=True)
    partial.write_text("")

    def progress(rec: dict) -> None:
        for line in rec.get("log", []):
            print(line, flush=True)
        with partial.open("a") as fh:  # each building's record as it finishes: a stopped run keeps them
            fh.write(json.dumps(rec, default=float) + "\n")
        print(f"done {rec['building']} ({time.perf_counter() - t0:.0f} s since start)"
              + (f": ERROR {rec['error']}" if "error" in rec else ""), flush=True)

    buildings = run_buildings(runs, settings, args.workers, progress)
    if args.placement_only:
        return _placement_report(buildings, args)
    return _report(buildings, args, {"seeds": [args.seeds.start, args.seeds.stop], "generators": args.generators,
                                     "appearance": args.appearance, "workers": args.workers,
                                     "overrides": args.overrides, "render_cost": render},
                   round(time.perf_counter() - t0, 1))


def _report(buildings: list[dict], args: argparse.Namespace, head: dict, run_wall_s: float | None) -> int:
    """Figures per building, totals, the table, NAME.json and NAME.png."""
    for b in buildings:
        if "error" not in b:
            b["figures"] = building_figures(b)
    t = totals(buildings)
    t["run_wall_s"] = run_wall_s
    print_table("Image-goal navigation per building (LiteVLoc; GT = ground-truth localization)", HEADER,
                table_rows(buildings))
    _print_totals(t)
    result = {"meta": run_meta(), **head, "buildings": buildings, "totals": t}  # --json keeps the machine too
    if args.json is None:
        write_json(args.name, result)
    else:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(result, indent=2, default=float) + "\n")
    png = (OUT / args.name if args.json is None else args.json).with_suffix(".png")
    print(f"plot: {plot(buildings, png, f'{args.name}: {len(buildings)} buildings')}")
    return 0


def _combined_report(args: argparse.Namespace) -> int:
    """`--combine`: the buildings of earlier runs' JSON / partial JSONL files in one report; a
    building named twice is an error (which record would count is not ours to choose)."""
    buildings: list[dict] = []
    loads: list[float] = []  # the parts' own (a combination's machine load says nothing about the runs)
    for f in args.combine:
        if not f.is_file():
            raise SystemExit(f"--combine: {f} not found")
        text = f.read_text()
        if f.suffix == ".jsonl":
            recs = [json.loads(line) for line in text.splitlines() if line.strip()]
        else:
            part = json.loads(text)
            recs = part["buildings"]
            loads += [part.get("meta", {}).get("load_avg") or 0.0]
        for r in recs:
            r.setdefault("source", str(f))
        buildings += recs
    names = [b["building"] for b in buildings]
    if len(set(names)) < len(names):
        raise SystemExit(f"--combine: buildings named twice: {sorted({n for n in names if names.count(n) > 1})}")
    head = {"meta": {**run_meta(), "load_avg": max(loads) if loads else None},
            "combined_from": [str(f) for f in args.combine],
            "generators": sorted({b["generator"] for b in buildings}),
            "seeds": sorted({int(b["seed"]) for b in buildings})}
    return _report(buildings, args, head, None)


def _placement_report(results: list[dict], args: argparse.Namespace) -> int:
    pt = placement_totals(results)
    rows = [[v, cam, x["images"], x["right"], x["wrong"], x["refused"], x["refusals"]]
            for v, cams in pt.items() for cam, x in cams.items()]
    print_table(f"Goal placement only, {len(results)} buildings (wrong: placed > 2 m from where the image was taken)",
                ["variant", "camera", "images", "right", "wrong", "refused", "refusals"], rows)
    result = {"meta": run_meta(), "seeds": [args.seeds.start, args.seeds.stop], "generators": args.generators,
              "placement": pt, "buildings": results}
    if args.json is None:
        write_json(args.name, result)
    else:
        args.json.write_text(json.dumps(result, indent=2, default=float) + "\n")
    return 0


def _print_totals(t: dict) -> None:
    lv, gt = t["litevloc"], t["ground-truth"]
    rows = [[mode, f"{x['reached']}/{x['goals']}", x["refused"], x["wrong_placements"], x["collisions"],
             x["buildings_without_collision"], x["lost_max_s"], x["never_fixed"], x["failures"]]
            for mode, x in (("LiteVLoc", lv), ("ground truth", gt))]
    print_table(f"Totals over {t['buildings']} buildings ({t['errors']} errors); path ratio {t['path_ratio']}, time "
                f"ratio {t['time_ratio']}"
                + (f"; {t['run_wall_s']} s wall for the run" if t["run_wall_s"] is not None else ""),
                ["localization", "reached", "refused", "wrong", "collisions", "buildings w/o collision",
                 "lost max s", "never fixed", "not reached, by reason"], rows)
    cams = t["by_camera"]
    print_table("By goal camera (driven goals; placement of every image of that camera)",
                ["camera", "driven", "reached LV", "reached GT", "images", "placed right", "placed wrong", "refused"],
                [[c, x["driven"], x["reached_litevloc"], x["reached_ground_truth"], x["images"], x["placed_right"],
                  x["placed_wrong"], x["refused"]] for c, x in cams.items()])
    print("acceptance: " + ", ".join(f"{k} {v[0]} ({'ok' if v[1] else 'NOT MET'})" for k, v in t["acceptance"].items()))


if __name__ == "__main__":
    raise SystemExit(main())
