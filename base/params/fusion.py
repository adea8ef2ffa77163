"""Parameters of the pose-graph fusion (`online.OnlineFusion`, `batch.refine_session`).

Kept free of GTSAM imports so the configuration tree can reference them cheaply.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from litevloc.base.settings import Settings, setting

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class FusionParams(Settings):
    """Parameters of `OnlineFusion` and `refine_session` (lengths m, angles deg, times s).

    Odometry increment noise (per axis, 1 sigma) for an increment of length d metres and
    rotation a radians: trans = odom_sigma_trans_floor + odom_sigma_trans_per_m * d,
    rot = odom_sigma_rot_floor_deg + odom_sigma_rot_per_m_deg * d + odom_sigma_rot_per_rad * a.
    VLoc sigmas are used when `add_vloc` gets no covariance.
    """

    keyframe_period_s: float = setting(
        0.1, "an odometry message becomes a smoother state when this much time passed since the last one", unit="s",
        low=0, low_open=True)
    keyframe_dist_m: float = setting(
        0.25, "an odometry message becomes a smoother state when the robot moved this far since the last one", unit="m",
        low=0, low_open=True)
    keyframe_angle_deg: float = setting(
        10.0, "an odometry message becomes a smoother state when the robot turned this far since the last one",
        unit="deg", low=0, low_open=True)
    lag_s: float = setting(
        3.0, "fixed-lag smoother window; must exceed the worst VLoc latency and 2 x keyframe_period_s", low=0,
        low_open=True, unit="s")
    odom_sigma_trans_floor: float = setting(
        0.002, "odometry increment translation noise, constant part (1 sigma per axis)", unit="m", low=0, low_open=True)
    odom_sigma_trans_per_m: float = setting(
        0.04, "odometry increment translation noise per metre of the increment", unit="m/m", low=0)
    odom_sigma_rot_floor_deg: float = setting(
        0.05, "odometry increment rotation noise, constant part (1 sigma per axis)", unit="deg", low=0, low_open=True)
    odom_sigma_rot_per_m_deg: float = setting(
        1.5, "odometry increment rotation noise per metre of the increment", unit="deg/m", low=0)
    odom_sigma_rot_per_rad: float = setting(
        0.02, "odometry increment rotation noise per radian turned", unit="rad/rad", low=0)
    vloc_sigma_trans: float = setting(
        0.05, "VLoc translation sigma when a VLoc pose comes without a covariance", unit="m", low=0, low_open=True)
    vloc_sigma_rot_deg: float = setting(
        2.0, "VLoc rotation sigma when a VLoc pose comes without a covariance", unit="deg", low=0, low_open=True)
    robust_kernel: Literal["huber", "cauchy", "none"] = setting("cauchy", "robust kernel on accepted VLoc priors")
    robust_k: float = setting(2.5, "robust kernel width (whitened units, sigmas)", low=0, low_open=True)
    gate_chi2: float = setting(
        22.46, "chi-square gate of a VLoc pose against the prediction (6 dof, p = 0.999; 0 = no gate)", low=0)
    init_votes: int = setting(2, "agreeing VLoc poses needed to initialise (1 = the first one)", low=1)
    init_max_trans_m: float = setting(
        0.5, "initialisation votes agree when their T_map_odom translations lie within this", low=0, low_open=True,
        unit="m")
    init_max_rot_deg: float = setting(
        10.0, "initialisation votes agree when their T_map_odom rotations lie within this", unit="deg", low=0,
        low_open=True)
    init_window_s: float = setting(
        5.0, "initialisation votes must be captured within this of the newest vote", low=0, low_open=True, unit="s")
    init_window_m: float = setting(
        2.5, "a vote older than init_window_s (a slow first fix) still counts when the odometry since travelled less "
        "than this", unit="m", low=0, low_open=True)
    init_window_deg: float = setting(
        45.0, "a vote older than init_window_s still counts when the odometry since also turned less than this in all",
        unit="deg", low=0, low_open=True)
    reinit_after_rejects: int = setting(
        5, "consecutive agreeing gated rejections that re-initialise the filter (0 = never)", low=0)
    covariance_period_s: float = setting(
        1.0, "at most one marginal covariance per this much sensor time", unit="s", low=0, low_open=True)
    odom_buffer_s: float = setting(
        60.0, "odometry kept for late VLoc poses (at least lag_s): a vote captured longer ago is refused as too old",
        unit="s", low=0, low_open=True)
    max_future_s: float = setting(
        0.05, "a VLoc pose up to this much newer than the newest odometry is extrapolated", unit="s", low=0)
    late_max_travel_m: float = setting(
        5.0, "a VLoc pose older than the smoother window is carried to it by odometry that moved less than this since "
        "(0 = off)", unit="m", low=0)
    late_max_turn_deg: float = setting(
        360.0, "a VLoc pose older than the smoother window is carried to it only when the odometry since turned less "
        "than this", unit="deg", low=0)
    odom_drift_yaw_deg_per_m: float = setting(
        0.5, "odometry heading drift its random-walk noise misses, 1 sigma per metre since the last accepted VLoc pose",
        unit="deg/m", low=0)
    odom_drift_trans_per_m: float = setting(
        0.02, "odometry scale drift its random-walk noise misses, along the net displacement since the last accepted "
        "VLoc pose (1 sigma)", unit="m/m", low=0)

    def check_relations(self) -> None:
        if self.lag_s < 2 * self.keyframe_period_s:
            raise ValueError(f"lag_s ({self.lag_s}) must be >= 2 * keyframe_period_s ({self.keyframe_period_s})")
        if self.odom_buffer_s < self.lag_s:
            raise ValueError(f"odom_buffer_s ({self.odom_buffer_s}) must be >= lag_s ({self.lag_s})")

    def odom_sigmas(self, dist_m: float, angle_rad: float) -> F64:
        """Per-axis sigmas of an odometry increment, GTSAM order (rot rad x3, trans m x3)."""
        rot = math.radians(self.odom_sigma_rot_floor_deg + self.odom_sigma_rot_per_m_deg * dist_m)
        rot += self.odom_sigma_rot_per_rad * angle_rad
        trans = self.odom_sigma_trans_floor + self.odom_sigma_trans_per_m * dist_m
        return np.array([rot, rot, rot, trans, trans, trans])

    def drift_sigmas(self, path_m: float) -> tuple[float, float, float]:
        """(heading rad, along-track m, sideways m) 1-sigma error that the odometry's systematic
        drift builds at most over `path_m` metres driven (a straight drive: a scale drift s gives
        s * L along the track, a constant heading drift rate b gives b * L of heading and
        b * L^2 / 2 sideways), so it outgrows the random-walk model (square root of L) on a long
        stretch. A bound for comparing two poses; the fusion's gate uses the path's own shape
        (`pipelines/fusion/drift.py`)."""
        b = math.radians(self.odom_drift_yaw_deg_per_m)
        return b * path_m, self.odom_drift_trans_per_m * path_m, 0.5 * b * path_m**2

    def vloc_cov_gtsam(self) -> F64:
        """Default VLoc covariance, GTSAM order."""
        r = math.radians(self.vloc_sigma_rot_deg) ** 2
        t = self.vloc_sigma_trans**2
        return np.diag([r, r, r, t, t, t])
