"""`litevloc record --config CFG -o RUN.mcap`: record the live camera (and odometry) to MCAP.

The recording uses the replayer's schema (`hw.streams.mcap_io`), so a robot run replays
later through `litevloc replay` / the runtime exactly as it was recorded
(hardware-in-the-loop). Sources:

* default: the configured source (`source.kind: oak-d` -> the OAK-D with the `camera`
  section; without a device this fails within `camera.discovery_timeout_s`, exit 2);
* `--source PATH`: any recording or dataset folder (`runtime.sources.open_source`, with
  simulated odometry as `convert` adds it), e.g. to test the recorder without hardware.

Live odometry is pluggable: `ODOMETRY_PROVIDERS` maps a name to a factory
`(LiteVLocConfig) -> OdometryFeed | None`. The default provider uses
`litevloc.hw.odometry.open_odometry(cfg)` when that module exists (the Zenoh
nav_msgs/Odometry input) and is skipped, with a log line, when it does not. A feed is an
iterable of `Odometry` (blocking iteration is fine: it runs on its own thread) with an
optional `close()`. Odometry that a `--source` already yields is recorded as is.

Stop with `--duration`, `--max-frames`, Ctrl-C or SIGTERM; the file is always finished
properly (written as RUN.mcap.partial, renamed when complete).
"""

from __future__ import annotations

import argparse
import importlib
import logging
import queue
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from types import FrameType
from typing import Any

from litevloc.config import LiteVLocConfig
from litevloc.hw.messages import GroundTruthPose, Message, Odometry, RgbdFrame
from litevloc.hw.streams.base import StreamSource
from litevloc.hw.streams.mcap_io import McapRecorder
from litevloc.runtime.cli.common import (
    add_config_args,
    add_frames_arg,
    add_json_arg,
    config_of,
    frames_of,
    progress,
    write_json,
)
from litevloc.runtime.cli.main import UserError

log = logging.getLogger(__name__)

OdometryFactory = Callable[[LiteVLocConfig], "Iterable[Odometry] | None"]


def _zenoh_odometry(cfg: LiteVLocConfig) -> Iterable[Odometry] | None:
    """The Zenoh odometry input (`litevloc.hw.odometry.open_odometry`), if installed and configured."""
    try:
        mod = importlib.import_module("litevloc.hw.odometry")
    except ImportError:
        log.info("odometry: litevloc.hw.odometry is not available; recording the camera only")
        return None
    opener = getattr(mod, "open_odometry", None)
    if opener is None:
        log.warning("odometry: litevloc.hw.odometry has no open_odometry(cfg); recording the camera only")
        return None
    feed: Iterable[Odometry] | None = opener(cfg)
    return feed


# name -> factory; tests and integrations may add or replace entries.
ODOMETRY_PROVIDERS: dict[str, OdometryFactory] = {"zenoh": _zenoh_odometry}


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


def open_camera_source(cfg: LiteVLocConfig, source: Path | None, frames: slice) -> StreamSource:
    """The source to record: `--source` if given, else the configured one (OAK-D, recording, dataset)."""
    from litevloc.runtime.sources import open_source, with_simulated_odometry

    if source is not None:
        src = open_source(source, frames, strict=True, rgbd_calibration=cfg.rgbd_calibration)
        return with_simulated_odometry(src, cfg.odometry_sim.rate_hz, cfg.odometry_sim.drift, cfg.odometry_sim.seed)
    kind = cfg.source.kind
    if kind == "oak-d":
        from litevloc.hw.oak import OakSource

        return OakSource(cfg.camera, strict=cfg.source.strict)
    if kind in ("recording", "dataset") and cfg.source.path:
        return open_source(cfg.source.path, frames, strict=True, rgbd_calibration=cfg.rgbd_calibration)
    raise UserError(
        f"nothing to record: the config's source.kind is {kind!r}"
        + ("" if cfg.source.path else " with no source.path")
        + "; use a config with source.kind: oak-d (e.g. --config oak-d) or pass --source PATH"
    )


class _OdometryPump:
    """Runs a (blocking) odometry iterable on a daemon thread into a queue."""

    def __init__(self, feed: Iterable[Odometry]) -> None:
        self.feed = feed
        self.q: queue.Queue[Odometry] = queue.Queue(maxsize=100_000)
        self.error: BaseException | None = None
        self.dropped = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="record-odometry", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        try:
            for msg in self.feed:
                if self._stop.is_set():
                    break
                try:
                    self.q.put_nowait(msg)
                except queue.Full:
                    self.dropped += 1
        except BaseException as exc:  # reported by the main thread
            self.error = exc

    def drain(self) -> list[Odometry]:
        out = []
        while True:
            try:
                out.append(self.q.get_nowait())
            except queue.Empty:
                return out

    def close(self) -> None:
        self._stop.set()
        closer = getattr(self.feed, "close", None)
        if callable(closer):
            closer()
        self._thread.join(timeout=2.0)


def _open_odometry(cfg: LiteVLocConfig, name: str) -> _OdometryPump | None:
    if name == "none":
        return None
    if name not in ODOMETRY_PROVIDERS:
        raise UserError(f"unknown --odometry {name!r}; choose from {[*ODOMETRY_PROVIDERS, 'none']}")
    feed = ODOMETRY_PROVIDERS[name](cfg)
    return None if feed is None else _OdometryPump(feed)


class _StopFlag:
    """Set by SIGINT/SIGTERM so the loop ends after the current message and the file is finished.

    A second signal raises KeyboardInterrupt (the partial file is then discarded).
    """

    def __init__(self) -> None:
        self.reason = ""

    def __call__(self, signum: int, frame: FrameType | None) -> None:
        if self.reason:
            raise KeyboardInterrupt
        self.reason = signal.Signals(signum).name


def record_stream(
    src: Iterable[Message],
    rec: McapRecorder,
    odometry: _OdometryPump | None = None,
    duration_s: float | None = None,
    max_frames: int | None = None,
    stop: _StopFlag | None = None,
    on_frame: Callable[[RgbdFrame], None] | None = None,
) -> tuple[dict[str, int], str]:
    """Write messages from `src` (and the odometry pump) until the source ends or a limit hits.

    Returns (counts by kind, why it stopped).
    """
    counts = {"frames": 0, "odometry": 0, "ground_truth": 0}
    t_end = None if duration_s is None else time.monotonic() + duration_s

    def write_odometry() -> None:
        if odometry is not None:
            for o in odometry.drain():
                rec.write(o)
                counts["odometry"] += 1

    why = "end of source"
    it: Iterator[Message] = iter(src)
    try:
        for msg in it:
            write_odometry()
            rec.write(msg)
            if isinstance(msg, RgbdFrame):
                counts["frames"] += 1
                if on_frame is not None:
                    on_frame(msg)
            elif isinstance(msg, Odometry):
                counts["odometry"] += 1
            elif isinstance(msg, GroundTruthPose):
                counts["ground_truth"] += 1
            if odometry is not None and odometry.error is not None:
                why = f"odometry input failed: {odometry.error}"
                break
            if max_frames is not None and counts["frames"] >= max_frames:
                why = f"{max_frames} frames"
                break
            if t_end is not None and time.monotonic() >= t_end:
                why = f"{duration_s:g} s"
                break
            if stop is not None and stop.reason:
                why = stop.reason
                break
    finally:
        close = getattr(it, "close", None)
        if callable(close):
            close()  # stops a live pipeline (generator cleanup)
        write_odometry()
    if odometry is not None and odometry.error is not None and not why.startswith("odometry"):
        why = f"odometry input failed: {odometry.error}"
    return counts, why


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
    src = open_camera_source(cfg, args.source, frames_of(args))  # fails fast without a device
    provider = args.odometry or ("none" if args.source is not None else "zenoh")
    odometry = _open_odometry(cfg, provider)
    meta: dict[str, Any] = {"recorder": "litevloc record", "source": src.name, "config": cfg.name}
    if src.__class__.__name__ == "OakSource":
        meta["camera"] = repr(cfg.camera)
    tmp = out.with_suffix(".mcap.partial")
    stop = _StopFlag()
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
