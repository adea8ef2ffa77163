"""Checks and frame handling of received odometry (config `runtime.odometry_checks`; used by
`litevloc.hw.odometry.OdometryChecker`)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from litevloc.base.geometry import check_rigid
from litevloc.base.settings import Settings, setting


@dataclass(frozen=True)
class OdometryCheckParams(Settings):
    """Checks and frame handling of received odometry (seconds; see module docstring)."""

    max_gap_s: float = setting(
        0.1, "a forward jump between consecutive odometry stamps beyond this is counted and flagged", unit="s", low=0,
        low_open=True)
    quat_norm_tolerance: float = setting(
        1e-3, "largest deviation of an odometry quaternion's norm from 1", low=0, low_open=True, high=0.5,
        high_open=True)
    frame_id: str = setting("", "expected header.frame_id of the odometry (\"\" = lock in the first one seen)")
    child_frame_id: str = setting("", "expected child_frame_id of the odometry (\"\" = accept any)")
    T_child_base: tuple[float, ...] = setting((), "T_child_base as 16 floats, row-major ([] = identity)", low=-math.inf)

    def check_relations(self) -> None:
        if self.T_child_base:
            if len(self.T_child_base) != 16:
                raise ValueError(f"T_child_base must have 16 numbers (4x4 row-major), got {len(self.T_child_base)}")
            check_rigid(np.asarray(self.T_child_base, dtype=np.float64).reshape(4, 4), "T_child_base")

    def child_to_base(self) -> NDArray[np.float64] | None:
        if not self.T_child_base:
            return None
        return np.asarray(self.T_child_base, dtype=np.float64).reshape(4, 4)
