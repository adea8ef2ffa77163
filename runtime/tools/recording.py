"""Recording a live camera (and odometry) to MCAP, the machinery of `litevloc record`.

The recording uses the replayer's schema (`hw.streams.mcap_io`), so a robot run replays later
through `litevloc replay` / the runtime exactly as it was recorded (hardware-in-the-loop).
Live odometry is pluggable: `ODOMETRY_PROVIDERS` maps a name to a factory
`(LiteVLocConfig) -> Iterable[Odometry] | None`. The default provider uses
`litevloc.hw.odometry.open_odometry(cfg)` (the Zenoh nav_msgs/Odometry input) and is skipped,
with a log line, when it is not available. A feed is an iterable of `Odometry` (blocking
iteration is fine: it runs on its own thread) with an optional `close()`.
"""

from __future__ import annotations

import importlib
import logging
import queue
import signal
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from types import FrameType

from litevloc.base.errors import LiteVLocError
from litevloc.config.schema import LiteVLocConfig
from litevloc.hw.messages import GroundTruthPose, Message, Odometry, RgbdFrame
from litevloc.hw.streams.base import StreamSource
from litevloc.hw.streams.mcap_io import McapRecorder

log = logging.getLogger(__name__)

OdometryFactory = Callable[[LiteVLocConfig], "Iterable[Odometry] | None"]


class RecordingError(LiteVLocError, ValueError):
    """Nothing to record, or an unknown odometry provider; the message says which."""


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


def open_camera_source(cfg: LiteVLocConfig, source: Path | None, frames: slice) -> StreamSource:
    """The source to record: `--source` if given, else the configured one (`source.kind`, opened
    through `runtime.sources.SOURCE_KINDS`: a camera, recording or dataset)."""
    from litevloc.runtime.sources import SourceUse, open_source, source_kind, with_simulated_odometry

    if source is not None:
        src = open_source(source, frames, strict=True, rgbd_calibration=cfg.rgbd_calibration)
        return with_simulated_odometry(src, cfg.odometry_sim.rate_hz, cfg.odometry_sim.drift, cfg.odometry_sim.seed)
    kind = source_kind(cfg.source.kind)
    if kind.recordable and (cfg.source.path or not kind.needs_path):
        return kind.open(cfg, frames, SourceUse.RECORD)
    raise RecordingError(
        f"nothing to record: the config's source.kind is {cfg.source.kind!r}"
        + ("" if cfg.source.path else " with no source.path")
        + "; use a config with source.kind: oak-d (e.g. --config oak-d) or pass --source PATH"
    )


class OdometryPump:
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


def open_odometry(cfg: LiteVLocConfig, name: str) -> OdometryPump | None:
    if name == "none":
        return None
    if name not in ODOMETRY_PROVIDERS:
        raise RecordingError(f"unknown --odometry {name!r}; choose from {[*ODOMETRY_PROVIDERS, 'none']}")
    feed = ODOMETRY_PROVIDERS[name](cfg)
    return None if feed is None else OdometryPump(feed)


class StopFlag:
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
    odometry: OdometryPump | None = None,
    duration_s: float | None = None,
    max_frames: int | None = None,
    stop: StopFlag | None = None,
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


