"""Rewrite the results from the benchmarks' own JSON (out/bench/*.json, out/demo/demo.json): the
headline figures table in README.md and docs/results/figures.md (one dated row per headline, with
the machine and the command), and the per-benchmark pages docs/results/<benchmark>.md (one dated
table each). A headline or page whose JSON is missing keeps what was last committed (said on stdout).

    python bench/report.py
"""

from __future__ import annotations

import argparse
from pathlib import Path

from litevloc.experiments.report import update_docs
from litevloc.experiments.result_pages import update_pages

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=ROOT / "out", help="folder holding bench/*.json and demo/demo.json")
    args = ap.parse_args()
    results = ROOT / "docs" / "results"
    update_docs(args.out, [ROOT / "README.md", results / "figures.md"])
    update_pages(args.out, results)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
