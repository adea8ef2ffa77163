"""Rewrite the headline figures table in README.md and docs/results/figures.md from the benchmarks'
own JSON (out/bench/*.json, out/demo/demo.json): one row per headline, dated, with the machine
and the command. A headline whose JSON is missing keeps its last committed row (said on stdout).

    python bench/report.py
"""

from __future__ import annotations

import argparse
from pathlib import Path

from litevloc.experiments.report import update_docs

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=ROOT / "out", help="folder holding bench/*.json and demo/demo.json")
    args = ap.parse_args()
    update_docs(args.out, [ROOT / "README.md", ROOT / "docs" / "results" / "figures.md"])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
