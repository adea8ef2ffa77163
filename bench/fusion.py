"""Fusion benchmark: `litevloc bench fusion` on the 7-Scenes query pass + a 30-minute
synthetic endurance run (`litevloc.experiments.fusion`). Prints the tables; writes
out/bench/fusion.json.

    .venv/bin/python bench/fusion.py [--minutes 30] [--seeds 5] [SRC]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import SEVEN_SCENES, write_json

from litevloc.base.frames import parse_frames
from litevloc.config import load_config
from litevloc.experiments.fusion import report, run_benchmark


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("src", nargs="?", type=Path, default=SEVEN_SCENES)
    ap.add_argument("--frames", default="500:1000", help="the query pass (default)")
    ap.add_argument("--minutes", type=float, default=30.0, help="synthetic run length (0 = skip)")
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--config", default="default")
    a = ap.parse_args()
    res = run_benchmark(a.src, parse_frames(a.frames), load_config(a.config), a.seeds, a.minutes)
    res["frames"] = a.frames
    print(report(res, a.seeds))
    write_json("fusion", res)
    return 0


if __name__ == "__main__":
    sys.exit(main())
