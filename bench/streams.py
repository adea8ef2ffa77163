"""Stream-layer throughput: dataset folder read vs MCAP replay (decode included).

Baseline = reading the same frames straight from the 7-Scenes folder (JPEG + PNG decode)
in the same run. Each measurement is repeated; medians are reported.

    python bench/streams.py [--frames 0:300] [--repeats 3]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import numpy as np
from _common import print_table, require_7scenes, write_json

from litevloc.base.frames import parse_frames
from litevloc.base.params.drift import DriftParams
from litevloc.hw.messages import RgbdFrame
from litevloc.hw.streams.mcap_io import McapRecorder, McapSource
from litevloc.runtime.sources import open_source, with_simulated_odometry


def timed_frames(src) -> tuple[float, int]:  # type: ignore[no-untyped-def]
    t0 = time.perf_counter()
    n = sum(1 for m in src if isinstance(m, RgbdFrame))
    return time.perf_counter() - t0, n


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--frames", default="0:300")
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    data = require_7scenes()
    frames = parse_frames(args.frames)
    with tempfile.TemporaryDirectory() as tmp:
        rec_path = Path(tmp) / "bench.mcap"
        conv, folder, replay = [], [], []
        for _ in range(args.repeats):
            src = with_simulated_odometry(open_source(data, frames), 100.0, DriftParams(), 0)
            t0 = time.perf_counter()
            with McapRecorder(rec_path) as rec:
                for m in src:
                    rec.write(m)
            conv.append(time.perf_counter() - t0)
            dt, n = timed_frames(open_source(data, frames))
            folder.append(dt)
            dt2, n2 = timed_frames(McapSource(rec_path))
            replay.append(dt2)
            assert n == n2
        size = rec_path.stat().st_size
    med = {k: float(np.median(v)) for k, v in {"convert": conv, "folder": folder, "replay": replay}.items()}
    rows = [
        ["7-Scenes folder read (baseline)", n / med["folder"], 1000 * med["folder"] / n, 1.0],
        ["MCAP replay (CDR + JPEG + depth decode)", n / med["replay"], 1000 * med["replay"] / n,
         med["folder"] / med["replay"]],
        ["convert folder -> MCAP (+100 Hz odometry)", n / med["convert"], 1000 * med["convert"] / n,
         med["folder"] / med["convert"]],
    ]
    print_table(f"Stream throughput, {n} frames 640x480, median of {args.repeats}",
                ["path", "frames/s", "ms/frame", "speed vs baseline"], rows)
    print(f"MCAP size: {size / n / 1e3:.0f} kB/frame")
    write_json("streams", {
        "frames": n, "repeats": args.repeats,
        "folder_fps": n / med["folder"], "replay_fps": n / med["replay"], "convert_fps": n / med["convert"],
        "replay_vs_folder_ratio": med["folder"] / med["replay"], "mcap_bytes_per_frame": size / n,
    })


if __name__ == "__main__":
    main()
