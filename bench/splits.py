"""Cross-split benchmark of 7-Scenes localization (issue #43): does it find what the map covers?

Eight splits by a rule fixed in advance (`litevloc.experiments.splits`, docs/localization.md):
maps of 250 contiguous frames queried with the block before and after (six), the published
split (map 0-499, queries 500-999) and its reverse. `B0>B1` and `B1>B0` choose parameters
(marked *), the others report. Per split: accepted, covered (a keyframe within 0.5 m / 30 deg;
"near": 1 m / 45 deg), accepted among covered, within [5 cm, 5 deg], median / max error,
poses > 0.5 m off, place-recognition recall@1/5/10 among covered frames, GL latency; and why
covered frames were refused. Maps are cached under out/bench/inputs/splits/, model calls under
out/cache/splits/ (replayed with their recorded time, see `experiments.model_replay`: latencies
are those of the run that first called the models, on this machine at that time).

    python bench/splits.py [--splits B0>B1 ...] [--step 1] [--set K=V ...] [--name splits]
        [--compare out/bench/splits_before.json]

Writes out/bench/NAME.json and NAME.png (accepted vs covered per split).

    python bench/splits.py --loop-probe [--set K=V ...] [--name splits_loop] [--compare OLD.json]

The loop probe instead (`experiments.splits_loop`, a safety check, not a split): GL from no prior
on every 200th frame of the simulated loop's query lap against the map of `bench/loop.py`
(out/bench/loop/map, built by it), its frames recorded under out/bench/inputs/loopgl/ and its
model calls under out/cache/loopgl/; accepted poses more than 0.5 m off are wrong fixes.

    python bench/splits.py --gl-latency [--splits published] [--step 10] --set K=V ...

GL latency instead (`experiments.splits_latency`): GL from no prior with the defaults and with
the --set overrides on the same frames, interleaved, models called live; medians and their ratio.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import INPUTS, OUT, ROOT, litevloc, print_table, require_7scenes, write_json

from litevloc.experiments.split_report import MAIN_COLUMNS, failure_rows, main_row, plot
from litevloc.experiments.splits import ensure_map, run_split, splits_named
from litevloc.experiments.splits_latency import gl_latency
from litevloc.experiments.splits_loop import run_loop_probe


def _build(argv: list[str]) -> int:
    """`map build` in a child process, as a user runs it (fails loudly)."""
    litevloc(*argv)
    return 0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--splits", nargs="*", default=[], help="split names (default: all eight)")
    ap.add_argument("--step", type=int, default=1, help="every STEP-th query frame (development subsets)")
    ap.add_argument("--config", default="7scenes")
    ap.add_argument("--set", dest="overrides", action="append", default=[])
    ap.add_argument("--name", default="splits")
    ap.add_argument("--compare", type=Path, help="an earlier run's JSON: its rows are printed beside")
    ap.add_argument("--loop-probe", action="store_true", help="run the loop probe instead of the splits")
    ap.add_argument("--gl-latency", action="store_true", help="GL latency, defaults vs --set, instead")
    args = ap.parse_args()
    if args.gl_latency:
        latency(args)
        return
    if args.loop_probe:
        loop_probe(args.overrides, args.name if args.name != "splits" else "splits_loop", args.compare)
        return
    data = require_7scenes()
    results = []
    for split in splits_named(args.splits):
        map_dir = ensure_map(data, split, INPUTS / "splits", args.config, _build)
        print(f"[{split.name}] map {map_dir.name}, queries {split.query_frames} step {args.step} ...", flush=True)
        r = run_split(split, map_dir, data, args.config, args.overrides, ROOT / "out" / "cache" / "splits",
                      args.step, on_frame=_progress(split.name))
        results.append(r)
        print(f"  {r['summary']['accepted']}/{r['summary']['queries']} accepted in {r['wall_s']:.0f} s "
              f"(model calls {r['model_calls']})", flush=True)
    before = json.loads(args.compare.read_text())["splits"] if args.compare else []
    rows = [main_row(r["split"], r["role"], r["summary"]) for r in results]
    if before:
        rows = [row for r in results for row in (main_row(r["split"], r["role"], r["summary"]),
                *(main_row(b["split"] + " (before)", b["role"], b["summary"]) for b in before
                  if b["split"] == r["split"]))]
    print_table(f"7-Scenes splits ({args.config} {' '.join(args.overrides)}; * = choosing split)",
                MAIN_COLUMNS, rows)
    header, reasons = failure_rows(results)
    if reasons:
        print_table("Covered frames refused, by reason", header, reasons)
    png = plot(results, OUT / f"{args.name}.png", before)
    print(f"plot: {png}")
    write_json(args.name, {"config": args.config, "overrides": args.overrides, "step": args.step,
                           "load_average": os.getloadavg(), "splits": results})


def latency(args: argparse.Namespace) -> None:
    """GL latency of the defaults vs `--set` on the first named split (default: published)."""
    split = splits_named(args.splits[:1] or ["published"])[0]
    data = require_7scenes()
    map_dir = ensure_map(data, split, INPUTS / "splits", args.config, _build)
    r = gl_latency(split, map_dir, data, args.config, args.overrides, args.step)
    print_table(f"GL latency, {split.name} every {args.step}th frame ({r['frames']}), models live, load average "
                f"{r['load_average_1min'][0]:.1f} -> {r['load_average_1min'][1]:.1f}",
                ["defaults ms", "with --set ms", "median ratio"],
                [[r["median_ms"]["base"], r["median_ms"]["new"], r["median_ratio"]]])
    write_json(args.name if args.name != "splits" else "splits_latency", r)


def loop_probe(overrides: list[str], name: str, compare: Path | None) -> None:
    """The loop probe (see the module docstring): per-frame lines, a summary row, JSON."""
    map_dir = OUT / "loop" / "map"
    if not (map_dir / "manifest.json").is_file():
        sys.exit(f"no loop map at {map_dir}: run `python bench/loop.py` first")
    r = run_loop_probe(map_dir, INPUTS / "loopgl", overrides, ROOT / "out" / "cache" / "loopgl",
                       on_frame=_progress("loop"))
    for f in r["frames"]:
        err = f"{f['error_m']:.2f} m" if f["accepted"] else "-"
        print(f"  frame {f['frame']:5d}: {err:>8}  {f['reason'][:110]}")
    cols = ["run", "queries", "accepted", "wrong", "max_error_m", "gl_ms_median"]
    runs = [("now", r["summary"])] + ([("before", json.loads(compare.read_text())["summary"])] if compare else [])
    print_table(f"Loop probe, GL from no prior (default {' '.join(overrides)}; wrong: > 0.5 m off)", cols,
                [[k] + [s[c] for c in cols[1:]] for k, s in runs])
    write_json(name, {"overrides": overrides, "load_average": os.getloadavg(), **r})


def _progress(name: str):  # type: ignore[no-untyped-def]
    def report(done: int, total: int) -> None:
        if done % 50 == 0 or done == total:
            print(f"  [{name}] {done}/{total}", flush=True)
    return report


if __name__ == "__main__":
    main()
