"""Noise parameters of the odometry drift model (`litevloc.pipelines.odometry_drift`) and the
base_link <- camera-optical rotation."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from litevloc.base.geometry import make_T
from litevloc.base.settings import Settings, setting


@dataclass(frozen=True)
class DriftParams(Settings):
    """Noise parameters of the odometry drift model (see module docstring)."""

    sigma_trans_per_m: float = setting(
        0.02, "translation noise per axis per metre travelled (1 sigma, fraction of the distance)", unit="m/m", low=0)
    sigma_trans_floor: float = setting(
        0.0005, "translation noise per axis that grows with time, not distance (1 sigma)", unit="m/sqrt(s)", low=0)
    sigma_rot_per_m: float = setting(
        float(np.radians(1.0)), "rotation noise per metre travelled (1 sigma)", unit="rad/m", low=0)
    sigma_rot_per_rad: float = setting(0.01, "rotation noise per radian turned (1 sigma)", unit="rad/rad", low=0)
    yaw_bias_per_m: float = setting(
        float(np.radians(0.5)), "constant yaw bias per metre travelled", unit="rad/m", low=-math.inf)


# base_link (x forward, y left, z up) <- camera optical (x right, y down, z forward).
R_BASE_OPTICAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


T_BASE_CAMERA_OPTICAL = make_T(R_BASE_OPTICAL, np.zeros(3))
