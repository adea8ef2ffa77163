"""Timestamped sensor messages shared by every stream source and sink.

All sources (dataset folders, MCAP recordings, the simulator, the OAK-D driver) yield
these, in non-decreasing `t_ns` order, so the rest of the system never sees a source's
own format.

* `RgbdFrame.color`: HxWx3 uint8, **RGB** channel order.
* `RgbdFrame.depth`: HxW float32 metres, **NaN = invalid** (zeros in files become NaN),
  or None when the source has no depth. Same size as `color` (registered).
* `RgbdFrame.K`: 3x3 float64 intrinsics of `color`.
* `RgbdFrame.color_jpeg`: the JPEG the colour was decoded from, when a source had one;
  recorders store it as is, so recording never re-encodes (no generation loss).
* `EncodedRgbdFrame`: a frame whose colour is still the source's compressed bytes. A source
  asked to defer decoding (`McapSource(defer_color=True)`) yields it to the service, where it
  passes the latest-frame mailbox as is and only the frames VLoc takes are decoded
  (`decode()`): the frames the mailbox drops are never decompressed.
* `Odometry.T_odom_base`: 4x4 pose of `base_link` in the `odom` frame.
* `GroundTruthPose.T_world_camera`: 4x4 pose of the camera optical frame in the
  dataset's world frame (the map frame for evaluation).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from litevloc.base.errors import LiteVLocError


class StreamError(LiteVLocError, RuntimeError):
    """A stream source or sink failed; the message names the file and the problem."""


@dataclass(frozen=True, eq=False)
class RgbdFrame:
    """One colour (+ depth) frame."""

    t_ns: int
    color: NDArray[np.uint8]
    depth: NDArray[np.float32] | None
    K: NDArray[np.float64]
    index: int = 0
    frame_id: str = "camera"
    color_jpeg: bytes | None = None  # the source's own JPEG bytes of `color`, if it had them

    @property
    def height(self) -> int:
        return int(self.color.shape[0])

    @property
    def width(self) -> int:
        return int(self.color.shape[1])


@dataclass(frozen=True, eq=False)
class EncodedRgbdFrame:
    """One colour (+ depth) frame with the colour not decoded yet (see the module docstring).

    `color_data`: the source's JPEG/PNG bytes; `depth` as in `RgbdFrame` (already metres,
    its size checked against the colour's at `decode`); `where` names the frame in errors.
    """

    t_ns: int
    color_data: bytes
    depth: NDArray[np.float32] | None
    K: NDArray[np.float64]
    index: int = 0
    frame_id: str = "camera"
    is_jpeg: bool = True  # keep the bytes as `RgbdFrame.color_jpeg` (recorders store them as is)
    where: str = ""

    def decode(self, decoder: Callable[[bytes, str], NDArray[np.uint8]] | None = None) -> RgbdFrame:
        """The decoded `RgbdFrame`; StreamError naming the frame when the colour does not decode
        or the depth's size differs from the colour's. `decoder(bytes, where) -> HxWx3 RGB`
        defaults to this module's `decode_color` (OpenCV)."""
        decoder = decode_color if decoder is None else decoder
        where = self.where or f"frame {self.index} at {self.t_ns} ns"
        color = decoder(self.color_data, where)
        if self.depth is not None and self.depth.shape != color.shape[:2]:
            raise StreamError(f"depth {self.depth.shape[1]}x{self.depth.shape[0]} does not match colour "
                              f"{color.shape[1]}x{color.shape[0]}: {where}")
        return RgbdFrame(t_ns=self.t_ns, color=color, depth=self.depth, K=self.K, index=self.index,
                         frame_id=self.frame_id, color_jpeg=self.color_data if self.is_jpeg else None)


def decode_color(data: bytes | NDArray[np.uint8], where: str) -> NDArray[np.uint8]:
    """Decode JPEG/PNG bytes to HxWx3 uint8 RGB; StreamError naming `where` if corrupt.

    A JPEG cut short decodes (libjpeg pads it grey) but is refused here: a JPEG must end
    with its EOI marker.
    """
    buf = np.frombuffer(data, dtype=np.uint8) if isinstance(data, bytes | bytearray | memoryview) else data
    if buf.size >= 2 and buf[0] == 0xFF and buf[1] == 0xD8 and not _jpeg_complete(buf):
        raise StreamError(f"colour JPEG is truncated (no end-of-image marker): {where}")
    import cv2  # here: importing the messages loads no OpenCV

    img = cv2.imdecode(buf, cv2.IMREAD_COLOR) if buf.size else None
    if img is None:
        raise StreamError(f"colour image is corrupt or not an image: {where}")
    return np.ascontiguousarray(img[:, :, ::-1])


def _jpeg_complete(buf: NDArray[np.uint8]) -> bool:
    tail = buf[-16:].tobytes()
    return b"\xff\xd9" in tail



@dataclass(frozen=True, eq=False)
class Odometry:
    """Proprioceptive odometry sample."""

    t_ns: int
    T_odom_base: NDArray[np.float64]
    covariance: NDArray[np.float64] | None = None  # 6x6, (x y z roll pitch yaw) order as ROS
    frame_id: str = "odom"
    child_frame_id: str = "base_link"


@dataclass(frozen=True, eq=False)
class GroundTruthPose:
    """Ground-truth camera pose (for evaluation only; never fed to localization)."""

    t_ns: int
    T_world_camera: NDArray[np.float64]
    index: int = 0
    frame_id: str = "world"


Message = RgbdFrame | Odometry | GroundTruthPose
SourceMessage = Message | EncodedRgbdFrame  # what a source asked to defer colour decoding yields


@dataclass
class StreamStats:
    """Counters a live or recorded source keeps of what it skipped and why."""

    messages: int = 0
    skipped: dict[str, int] = field(default_factory=dict)

    def skip(self, reason: str) -> None:
        self.skipped[reason] = self.skipped.get(reason, 0) + 1

    @property
    def total_skipped(self) -> int:
        return sum(self.skipped.values())


def depth_from_units(raw: NDArray[np.integer], units_per_metre: float) -> NDArray[np.float32]:
    """Integer depth (0 = invalid) -> float32 metres with NaN for invalid.

    The one conversion every reader uses, so the same stored value always gives the
    same float (bit-exact round trips through recordings).
    """
    d = np.asarray(raw).astype(np.float32) / np.float32(units_per_metre)
    d[np.asarray(raw) == 0] = np.nan
    return d


def depth_from_millimetres(depth_mm: NDArray[np.integer]) -> NDArray[np.float32]:
    """uint16 millimetres (0 = invalid) -> float32 metres with NaN for invalid."""
    return depth_from_units(depth_mm, 1000.0)


def depth_to_millimetres(depth_m: NDArray[np.floating]) -> NDArray[np.uint16]:
    """float metres (NaN/<=0 invalid) -> uint16 millimetres with 0 for invalid.

    Depths beyond 65.535 m are marked invalid rather than wrapped.
    """
    d = np.asarray(depth_m, dtype=np.float64)
    valid = np.isfinite(d) & (d > 0) & (d * 1000.0 <= 65535.0)
    out = np.zeros(d.shape, dtype=np.uint16)
    out[valid] = np.round(d[valid] * 1000.0).astype(np.uint16)
    return out
