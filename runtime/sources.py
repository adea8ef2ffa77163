"""Open any supported input as a `StreamSource`, adding simulated odometry where asked.

Folders are detected (7-Scenes, TUM RGB-D); `.mcap` files are recordings. For posed
datasets without odometry, `with_simulated_odometry` interleaves drift-model odometry
(`pipelines.odometry_drift`) with the frames in time order. Camera and base_link are
related by `T_BASE_CAMERA_OPTICAL` (base_link = the camera, in REP-103 body axes).

`SOURCE_KINDS` is the one registry of the config's `source.kind` values: each names how its
source is opened and what it needs. Both dispatchers (`litevloc run`, `cli.run`, and
`litevloc record`, `runtime.tools.recording`) open the configured source through `source_kind`,
so a new camera driver is its `StreamSource` module plus one entry here.
"""

from __future__ import annotations

import dataclasses
import enum
import heapq
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from litevloc.base.geometry import invert
from litevloc.base.params.calibration import ColorDepthCalibration
from litevloc.base.params.drift import T_BASE_CAMERA_OPTICAL, DriftParams
from litevloc.config.schema import LiteVLocConfig
from litevloc.hw.messages import Message, Odometry, SourceMessage, StreamError, StreamStats
from litevloc.hw.streams.base import StreamSource
from litevloc.hw.streams.mcap_io import McapSource
from litevloc.hw.streams.posed_folder import PosedFolderSource
from litevloc.hw.streams.sevenscenes import SevenScenesSource, is_sevenscenes_folder
from litevloc.hw.streams.tum import TumRgbdSource, is_tum_folder
from litevloc.pipelines.odometry_drift import simulate_odometry


def open_source(
    path: str | Path, frames: slice = slice(None), strict: bool = True,
    rgbd_calibration: ColorDepthCalibration | None = None,
) -> StreamSource:
    """Open a dataset folder, a recording, or a simulator URI (`sim:office?pass=query&seed=1`);
    StreamError with a clear message otherwise. `frames` does not apply to simulator URIs.
    `rgbd_calibration` (config `rgbd_calibration`) registers 7-Scenes depth to the colour
    camera (see hw/streams/sevenscenes.py); other inputs are already registered and ignore it."""
    if str(path).startswith("sim:"):
        from litevloc.sim.source import open_sim_source

        try:
            return open_sim_source(str(path))
        except ValueError as exc:
            raise StreamError(str(exc)) from exc
    p = Path(path)
    if not p.exists():
        raise StreamError(f"input not found: {p}")
    if p.is_file():
        if p.suffix.lower() == ".mcap":
            return McapSource(p, frames, strict=strict)
        raise StreamError(f"{p}: unsupported file type (expected a .mcap recording)")
    if is_sevenscenes_folder(p):
        if rgbd_calibration is not None:
            return SevenScenesSource(p, frames, strict=strict, K_color=rgbd_calibration.K_color(),
                                     T_color_depth=rgbd_calibration.T_color_depth(),
                                     depth_dilation=rgbd_calibration.depth_dilation,
                                     color_k1_k2=(rgbd_calibration.color_k1, rgbd_calibration.color_k2))
        return SevenScenesSource(p, frames, strict=strict)
    if is_tum_folder(p):
        return TumRgbdSource(p, frames, strict=strict)
    raise StreamError(f"{p}: not a 7-Scenes folder (frame-NNNNNN.color.jpg) nor a TUM folder (rgb.txt)")


class SourceUse(enum.Enum):
    """What the configured source is opened for."""

    SERVICE = "service"  # `litevloc run`: the onboard service reads it
    RECORD = "record"  # `litevloc record`: it is copied to an MCAP file


SourceOpener = Callable[[LiteVLocConfig, slice, SourceUse], StreamSource]


@dataclass(frozen=True)
class SourceKind:
    """One `source.kind`: `open(cfg, frames, use)` -> the source (`frames`: a slice over frame
    indices, for sources that have them); `needs_path`: it reads `source.path` (refused when
    empty); `recordable`: `litevloc record` can record it from the config."""

    open: SourceOpener
    needs_path: bool = False
    recordable: bool = True


def _open_path(cfg: LiteVLocConfig, frames: slice, use: SourceUse) -> StreamSource:
    # a recording checks every message as it copies it; the service skips bad ones if so configured
    strict = True if use is SourceUse.RECORD else cfg.source.strict
    return open_source(cfg.source.path, frames, strict=strict, rgbd_calibration=cfg.rgbd_calibration)


def _open_oak(cfg: LiteVLocConfig, frames: slice, use: SourceUse) -> StreamSource:
    from litevloc.hw.oak import OakSource

    camera = cfg.camera
    if use is SourceUse.SERVICE:
        # `camera.jpeg_quality` is the JPEG round trip that makes a recording's pixels the live
        # ones; the service records nothing, so it takes the raw colour
        camera = dataclasses.replace(camera, jpeg_quality=0)
    return OakSource(camera, strict=cfg.source.strict)


# source.kind -> how it is opened; integrations and tests may add entries
SOURCE_KINDS: dict[str, SourceKind] = {
    "recording": SourceKind(_open_path, needs_path=True),
    "dataset": SourceKind(_open_path, needs_path=True),
    "sim": SourceKind(_open_path, needs_path=True, recordable=False),
    "oak-d": SourceKind(_open_oak),
}


def source_kind(name: str) -> SourceKind:
    """The registry entry of a `source.kind`; StreamError naming the known kinds otherwise."""
    if name not in SOURCE_KINDS:
        raise StreamError(f"unknown source.kind {name!r}; known kinds: {', '.join(sorted(SOURCE_KINDS))}")
    return SOURCE_KINDS[name]


def service_messages(src: StreamSource, reader_process: bool = False) -> Iterable[SourceMessage]:
    """What the service reads from `src`: a recording read non-strictly gives its frames with
    the colour undecoded (the service decodes only the frames VLoc takes, after the mailbox
    that drops the stale ones); every other source (and a strict read, which checks each
    frame as it reads it) is read as it is. `reader_process` (config `runtime.recording_process`):
    such a recording is read in a child process (`runtime.recording_process`), so its decoding
    does not hold the service's GIL."""
    if isinstance(src, McapSource) and not src.strict:
        if reader_process:
            from litevloc.runtime.recording_process import RecordingReaderProcess

            return RecordingReaderProcess(src)
        return src.messages(defer_color=True)
    return src


class SimulatedOdometrySource:
    """A posed folder source plus drift-model odometry, merged in time order."""

    def __init__(self, inner: PosedFolderSource, rate_hz: float, params: DriftParams, seed: int) -> None:
        self.inner = inner
        self.name = inner.name + f"+odom@{rate_hz:g}Hz"
        self.stats: StreamStats = inner.stats
        times, T_world_cam = inner.ground_truth()
        if len(times) < 2:
            raise StreamError(f"{inner.name}: need >= 2 ground-truth poses to simulate odometry")
        T_world_base = T_world_cam @ invert(T_BASE_CAMERA_OPTICAL)
        self.odom_times, self.T_odom_base = simulate_odometry(times, T_world_base, rate_hz, params, seed)

    def frame_count(self) -> int:
        return self.inner.frame_count()

    def _odometry(self) -> Iterator[Message]:
        for t, T in zip(self.odom_times, self.T_odom_base, strict=True):
            yield Odometry(int(t), np.asarray(T))

    def __iter__(self) -> Iterator[Message]:
        # Odometry sorts before a frame with the same stamp (key ties broken by order).
        return heapq.merge(self._odometry(), iter(self.inner), key=lambda m: m.t_ns)


def with_simulated_odometry(src: StreamSource, rate_hz: float, params: DriftParams, seed: int) -> StreamSource:
    """Add simulated odometry to a posed folder source; recordings are returned unchanged."""
    if rate_hz <= 0 or not isinstance(src, PosedFolderSource):
        return src
    return SimulatedOdometrySource(src, rate_hz, params, seed)
