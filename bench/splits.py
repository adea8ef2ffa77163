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
    args = ap.parse_args()
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


def _progress(name: str):  # type: ignore[no-untyped-def]
    def report(done: int, total: int) -> None:
        if done % 50 == 0 or done == total:
            print(f"  [{name}] {done}/{total}", flush=True)
    return report


if __name__ == "__main__":
    main()
