"""Noise parameters of the odometry drift model (`litevloc.pipelines.odometry_drift`) and the
base_link <- camera-optical rotation."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from litevloc.base.geometry import make_T


@dataclass(frozen=True)
class DriftParams:
    """Noise parameters of the odometry drift model (see module docstring)."""

    # translation noise per axis, per metre travelled (1 sigma, fraction of the distance)
    sigma_trans_per_m: float = 0.02
    # translation noise per axis that grows with time, not distance (m per sqrt(s), 1 sigma)
    sigma_trans_floor: float = 0.0005
    # rotation noise per metre travelled (rad/m, 1 sigma)
    sigma_rot_per_m: float = float(np.radians(1.0))
    # rotation noise per radian turned (rad/rad, 1 sigma)
    sigma_rot_per_rad: float = 0.01
    # constant yaw bias per metre travelled (rad/m)
    yaw_bias_per_m: float = float(np.radians(0.5))

    def __post_init__(self) -> None:
        for name in ("sigma_trans_per_m", "sigma_trans_floor", "sigma_rot_per_m", "sigma_rot_per_rad"):
            v = getattr(self, name)
            if not np.isfinite(v) or v < 0:
                raise ValueError(f"{name} must be a finite number >= 0, got {v}")
        if not np.isfinite(self.yaw_bias_per_m):
            raise ValueError("yaw_bias_per_m must be finite")


# base_link (x forward, y left, z up) <- camera optical (x right, y down, z forward).
R_BASE_OPTICAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


T_BASE_CAMERA_OPTICAL = make_T(R_BASE_OPTICAL, np.zeros(3))
