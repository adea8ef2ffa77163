"""`litevloc replay REC`: play a recording with its timing and summarise it."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from litevloc.hw.messages import GroundTruthPose, Odometry, RgbdFrame
from litevloc.runtime.cli.common import (
    add_config_args,
    add_frames_arg,
    add_json_arg,
    config_of,
    frames_of,
    progress,
    write_json,
)
from litevloc.runtime.pacing import paced
from litevloc.runtime.sources import open_source


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("replay", help="play a recording (or dataset folder) with its recorded timing")
    p.add_argument("rec", type=Path, help=".mcap recording (or dataset folder)")
    p.add_argument("--rate", type=float, default=None,
                   help="real-time factor (default from config: 1; 0 = as fast as possible)")
    add_frames_arg(p)
    add_config_args(p)
    add_json_arg(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    cfg = config_of(args)
    rate = cfg.replay.rate if args.rate is None else args.rate
    if rate < 0:
        from litevloc.runtime.cli.main import UserError

        raise UserError("--rate must be >= 0")
    src = open_source(args.rec, frames_of(args), strict=False)
    counts = {"frames": 0, "odometry": 0, "ground_truth": 0}
    first = last = None
    t0 = time.perf_counter()
    with progress(src.frame_count(), "replay") as bar:
        for msg in paced(src, rate):
            first = msg.t_ns if first is None else first
            last = msg.t_ns
            if isinstance(msg, RgbdFrame):
                counts["frames"] += 1
                bar.update(1)
            elif isinstance(msg, Odometry):
                counts["odometry"] += 1
            elif isinstance(msg, GroundTruthPose):
                counts["ground_truth"] += 1
    wall = time.perf_counter() - t0
    sensor_s = 0.0 if first is None or last is None else (last - first) * 1e-9
    fps = counts["frames"] / max(wall, 1e-9)
    skipped = src.stats.skipped
    print(
        f"replayed {src.name}: {counts['frames']} frames, {counts['odometry']} odometry, "
        f"{counts['ground_truth']} ground-truth poses over {sensor_s:.2f} s of sensor time "
        f"in {wall:.2f} s wall ({fps:.1f} frames/s, rate {rate:g}); skipped {sum(skipped.values())}"
        + (f" {skipped}" if skipped else "")
    )
    write_json(args.json, {**counts, "sensor_seconds": sensor_s, "wall_seconds": wall, "frames_per_second": fps,
                           "rate": rate, "skipped": skipped, "source": src.name})
    return 0
