"""Fusion benchmark: `litevloc bench fusion` on the 7-Scenes query pass + a 30-minute
synthetic endurance run. Prints the tables; writes out/bench/fusion.json.

    .venv/bin/python bench/fusion.py [--minutes 30] [--seeds 5] [SRC]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from litevloc.runtime.cli.main import main

ROOT = Path(__file__).resolve().parents[1]


def run() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    default_src = ROOT.parent / "shared" / "data" / "7scenes-redkitchen"
    ap.add_argument("src", nargs="?", default=str(default_src))
    ap.add_argument("--minutes", type=float, default=30.0, help="synthetic run length (0 = skip)")
    ap.add_argument("--seeds", type=int, default=5)
    a = ap.parse_args()
    out = ROOT / "out" / "bench" / "fusion.json"
    return main([
        "bench", "fusion", a.src, "--frames", "500:1000", "--seeds", str(a.seeds),
        "--synthetic-minutes", str(a.minutes), "--json", str(out),
    ])


if __name__ == "__main__":
    sys.exit(run())
