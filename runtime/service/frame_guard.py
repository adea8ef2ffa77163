"""Frame checks in front of VLoc: a malformed frame is a counted, rejected VLoc result, never
an exception in the VLoc stage (which would stop the service).

Checked (reason names as counted in `FrameGuard.skipped` and shown as the VLoc reason):
colour HxWx3 uint8 with 32 <= H, W <= 4096; depth present, HxW (same as colour), float32 or
float64 (NaN = invalid; all-invalid depth is left to VLoc, which rejects it); K 3x3 finite
with fx, fy > 0 and last row (0, 0, 1); stamp a non-negative int.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from litevloc.pipelines.localization.tracking import TrackingState

MIN_SIDE, MAX_SIDE = 32, 4096


@dataclass(frozen=True)
class RejectedFrame:
    """The VLoc result for a frame that failed the checks (fields as LocalizationResult's)."""

    t_ns: int
    accepted: bool
    reason: str
    T_map_camera: None = None
    covariance: None = None
    timings_ms: Mapping[str, float] = field(default_factory=dict)
    provisional: None = None
    tracking_state: TrackingState | None = None


def frame_problem(frame: Any) -> str | None:
    """None if `frame` (an `hw.messages.RgbdFrame`) can go into VLoc, else a short reason."""
    c, d, K = getattr(frame, "color", None), getattr(frame, "depth", None), getattr(frame, "K", None)
    if not isinstance(c, np.ndarray) or c.ndim != 3 or c.shape[2] != 3:
        return "bad colour shape"
    if c.dtype != np.uint8:
        return "bad colour dtype"
    h, w = c.shape[:2]
    if not (MIN_SIDE <= h <= MAX_SIDE and MIN_SIDE <= w <= MAX_SIDE):
        return "bad colour size"
    if d is None:
        return "no depth"
    if not isinstance(d, np.ndarray) or d.shape != (h, w):
        return "depth size mismatch"
    if d.dtype not in (np.float32, np.float64):
        return "bad depth dtype"
    if not isinstance(K, np.ndarray) or K.shape != (3, 3) or not np.all(np.isfinite(K)):
        return "bad intrinsics"
    if not (K[0, 0] > 0 and K[1, 1] > 0 and np.allclose(K[2], (0.0, 0.0, 1.0))):
        return "bad intrinsics"
    t = getattr(frame, "t_ns", None)
    if not isinstance(t, int | np.integer) or t < 0:
        return "bad stamp"
    return None


class FrameGuard:
    """Wraps `vloc(frame, prior)`: bad frames are answered with a `RejectedFrame` (counted)."""

    def __init__(self, vloc: Callable[[Any, Any], Any]) -> None:
        self.vloc = vloc
        self.skipped: dict[str, int] = {}

    def __call__(self, frame: Any, prior: Any) -> Any:
        why = frame_problem(frame)
        if why is not None:
            self.skipped[why] = self.skipped.get(why, 0) + 1
            t = getattr(frame, "t_ns", 0)
            return RejectedFrame(int(t) if isinstance(t, int | np.integer) else 0, False, f"bad frame: {why}")
        if frame.depth.dtype != np.float32:
            import dataclasses

            frame = dataclasses.replace(frame, depth=frame.depth.astype(np.float32))
        return self.vloc(frame, prior)
