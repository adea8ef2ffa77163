"""`litevloc record --config CFG -o RUN.mcap`: record the live camera (and odometry) to MCAP
(`runtime.tools.recording`). Sources:

* default: the configured source (`source.kind: oak-d` -> the OAK-D with the `camera`
  section; without a device this fails within `camera.discovery_timeout_s`, exit 2);
* `--source PATH`: any recording or dataset folder (`runtime.sources.open_source`, with
  simulated odometry as `convert` adds it), e.g. to test the recorder without hardware.

Live odometry comes from `runtime.tools.recording.ODOMETRY_PROVIDERS` (`--odometry NAME`); odometry
that a `--source` already yields is recorded as is.

Stop with `--duration`, `--max-frames`, Ctrl-C or SIGTERM; the file is always finished
properly (written as RUN.mcap.partial, renamed when complete).
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
import time
from pathlib import Path
from typing import Any

from litevloc.cli.common import add_config_args, add_frames_arg, add_json_arg, config_of, frames_of
from litevloc.cli.main import UserError
from litevloc.hw.streams.mcap_io import McapRecorder
from litevloc.runtime.tools.outputs import progress, write_json
from litevloc.runtime.tools.recording import (
    ODOMETRY_PROVIDERS,
    RecordingError,
    StopFlag,
    open_camera_source,
    open_odometry,
    record_stream,
)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("record", help="record the live camera (OAK-D) and odometry to an MCAP recording")
    p.add_argument("-o", "--output", type=Path, required=True, metavar="RUN.mcap", help="output .mcap file")
    p.add_argument("--duration", type=float, default=None, metavar="S", help="stop after S seconds (wall clock)")
    p.add_argument("--max-frames", type=int, default=None, metavar="N", help="stop after N camera frames")
    p.add_argument("--source", type=Path, default=None, metavar="REC_OR_DATASET",
                   help="record from a recording or dataset folder instead of the configured live source")
    p.add_argument("--odometry", default=None, metavar="NAME",
                   help=f"live odometry provider ({', '.join(ODOMETRY_PROVIDERS)}, or 'none'); default zenoh for "
                        "the live camera, none with --source (a recording brings its own odometry)")
    add_frames_arg(p)
    add_config_args(p)
    add_json_arg(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    cfg = config_of(args)
    out: Path = args.output
    if out.suffix.lower() != ".mcap":
        raise UserError(f"output must be a .mcap file, got {out}")
    if args.source is not None and out.resolve() == args.source.resolve():
        raise UserError("output would overwrite the input")
    if args.duration is not None and not args.duration > 0:
        raise UserError("--duration must be > 0 seconds")
    if args.max_frames is not None and args.max_frames <= 0:
        raise UserError("--max-frames must be > 0")
    try:
        src = open_camera_source(cfg, args.source, frames_of(args))  # fails fast without a device
        odometry = open_odometry(cfg, args.odometry or ("none" if args.source is not None else "zenoh"))
    except RecordingError as exc:
        raise UserError(str(exc)) from exc
    meta: dict[str, Any] = {"recorder": "litevloc record", "source": src.name, "config": cfg.name}
    if src.__class__.__name__ == "OakSource":
        meta["camera"] = repr(cfg.camera)
    tmp = out.with_suffix(".mcap.partial")
    stop = StopFlag()
    handlers = {}
    if threading.current_thread() is threading.main_thread():
        handlers = {sig: signal.signal(sig, stop) for sig in (signal.SIGINT, signal.SIGTERM)}
    t0 = time.perf_counter()
    try:
        total = src.frame_count() or None
        if args.max_frames is not None:
            total = min(total, args.max_frames) if total else args.max_frames
        with McapRecorder(tmp, metadata={k: str(v) for k, v in meta.items()}) as rec, \
                progress(total, "record") as bar:
            counts, why = record_stream(src, rec, odometry, args.duration, args.max_frames, stop,
                                        on_frame=lambda _f: bar.update(1))
        tmp.replace(out)
    finally:
        tmp.unlink(missing_ok=True)
        if odometry is not None:
            odometry.close()
        for sig, handler in handlers.items():
            signal.signal(sig, handler)
    dt = time.perf_counter() - t0
    size = out.stat().st_size
    skipped = dict(src.stats.skipped)
    print(
        f"recorded {out}: {counts['frames']} frames, {counts['odometry']} odometry, "
        f"{counts['ground_truth']} ground-truth poses, {size / 1e6:.1f} MB in {dt:.1f} s "
        f"(stopped: {why}); skipped {sum(skipped.values())}" + (f" {skipped}" if skipped else "")
        + (f"; odometry dropped {odometry.dropped}" if odometry is not None and odometry.dropped else "")
    )
    write_json(args.json, {"output": str(out), **counts, "bytes": size, "seconds": dt, "stopped": why,
                           "source": src.name, "skipped": skipped,
                           "odometry_dropped": 0 if odometry is None else odometry.dropped})
    if why.startswith("odometry input failed"):
        print(f"litevloc record: error: {why} (the recording up to that point was kept)", file=sys.stderr)
        return 1
    return 0
