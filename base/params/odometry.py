"""Checks and frame handling of received odometry (config `runtime.odometry_checks`; used by
`litevloc.hw.odometry.OdometryChecker`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from litevloc.base.geometry import check_rigid


@dataclass(frozen=True)
class OdometryCheckParams:
    """Checks and frame handling of received odometry (seconds; see module docstring)."""

    # a forward jump between consecutive stamps beyond this is counted and flagged (s)
    max_gap_s: float = 0.1
    # largest deviation of a quaternion's norm from 1
    quat_norm_tolerance: float = 1e-3
    # expected header.frame_id; "" = lock in the first one seen
    frame_id: str = ""
    # expected child_frame_id; "" = accept any
    child_frame_id: str = ""
    # T_child_base as 16 floats, row-major; [] = identity
    T_child_base: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        if not (self.max_gap_s > 0 and np.isfinite(self.max_gap_s)):
            raise ValueError(f"max_gap_s must be a finite number > 0, got {self.max_gap_s}")
        if not (0 < self.quat_norm_tolerance < 0.5):
            raise ValueError(f"quat_norm_tolerance must be in (0, 0.5), got {self.quat_norm_tolerance}")
        if self.T_child_base:
            if len(self.T_child_base) != 16:
                raise ValueError(f"T_child_base must have 16 numbers (4x4 row-major), got {len(self.T_child_base)}")
            check_rigid(np.asarray(self.T_child_base, dtype=np.float64).reshape(4, 4), "T_child_base")

    def child_to_base(self) -> NDArray[np.float64] | None:
        if not self.T_child_base:
            return None
        return np.asarray(self.T_child_base, dtype=np.float64).reshape(4, 4)
