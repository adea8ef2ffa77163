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
* `Odometry.T_odom_base`: 4x4 pose of `base_link` in the `odom` frame.
* `GroundTruthPose.T_world_camera`: 4x4 pose of the camera optical frame in the
  dataset's world frame (the map frame for evaluation).
"""

from __future__ import annotations

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
