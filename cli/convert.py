"""`litevloc convert SRC DST.mcap`: dataset folder (or recording) -> MCAP recording."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from litevloc.cli.common import add_config_args, add_frames_arg, add_json_arg, config_of, source_of
from litevloc.cli.main import UserError
from litevloc.hw.streams.mcap_io import record_messages
from litevloc.runtime.sources import with_simulated_odometry
from litevloc.runtime.tools.outputs import progress, write_json


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("convert", help="convert a dataset folder (7-Scenes, TUM RGB-D) to an MCAP recording")
    p.add_argument("src", type=Path, help="dataset folder or .mcap recording")
    p.add_argument("dst", type=Path, help="output .mcap file")
    add_frames_arg(p)
    p.add_argument("--odometry-rate", type=float, default=None, metavar="HZ",
                   help="simulated odometry rate for posed datasets (default from config: 100; 0 = none)")
    p.add_argument("--seed", type=int, default=None, help="seed of the odometry drift model (default from config: 0)")
    add_config_args(p)
    add_json_arg(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    cfg = config_of(args)
    if args.dst.suffix.lower() != ".mcap":
        raise UserError(f"output must be a .mcap file, got {args.dst}")
    if args.dst.resolve() == args.src.resolve():
        raise UserError("output would overwrite the input")
    rate = cfg.odometry_sim.rate_hz if args.odometry_rate is None else args.odometry_rate
    seed = cfg.odometry_sim.seed if args.seed is None else args.seed
    if rate < 0:
        raise UserError("--odometry-rate must be >= 0")
    src = source_of(args, cfg)
    src = with_simulated_odometry(src, rate, cfg.odometry_sim.drift, seed)
    t0 = time.perf_counter()
    meta = {"source": str(args.src), "frames": args.frames or ":", "odometry_rate_hz": str(rate), "seed": str(seed),
            "drift_model": repr(cfg.odometry_sim.drift)}
    with progress(src.frame_count(), "convert") as bar:
        counts = record_messages(src, args.dst, meta, on_frame=lambda: bar.update(1))
    dt = time.perf_counter() - t0
    size = args.dst.stat().st_size
    print(
        f"wrote {args.dst}: {counts['frames']} frames, {counts['odometry']} odometry, "
        f"{counts['ground_truth']} ground-truth poses, {size / 1e6:.1f} MB in {dt:.1f} s "
        f"({counts['frames'] / max(dt, 1e-9):.1f} frames/s)"
    )
    write_json(args.json, {"output": str(args.dst), **counts, "bytes": size, "seconds": dt,
                           "odometry_rate_hz": rate, "seed": seed, "skipped": src.stats.skipped})
    return 0
