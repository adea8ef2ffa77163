"""Parameters of the pose-graph fusion (`online.OnlineFusion`, `batch.refine_session`).

Kept free of GTSAM imports so the configuration tree can reference them cheaply.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class FusionParams:
    """Parameters of `OnlineFusion` and `refine_session` (lengths m, angles deg, times s).

    Odometry increment noise (per axis, 1 sigma) for an increment of length d metres and
    rotation a radians: trans = odom_sigma_trans_floor + odom_sigma_trans_per_m * d,
    rot = odom_sigma_rot_floor_deg + odom_sigma_rot_per_m_deg * d + odom_sigma_rot_per_rad * a.
    VLoc sigmas are used when `add_vloc` gets no covariance.
    """

    # an odometry message becomes a smoother state when this much time passed since the last (s)
    keyframe_period_s: float = 0.1
    # ... or the robot moved this far (m)
    keyframe_dist_m: float = 0.25
    # ... or turned this far (degrees)
    keyframe_angle_deg: float = 10.0
    # fixed-lag smoother window (s); must exceed the worst VLoc latency
    lag_s: float = 3.0
    # odometry increment translation noise, constant part (m, 1 sigma per axis)
    odom_sigma_trans_floor: float = 0.002
    # odometry increment translation noise per metre of the increment (m/m)
    odom_sigma_trans_per_m: float = 0.04
    # odometry increment rotation noise, constant part (degrees, 1 sigma per axis)
    odom_sigma_rot_floor_deg: float = 0.05
    # odometry increment rotation noise per metre of the increment (deg/m)
    odom_sigma_rot_per_m_deg: float = 1.5
    # odometry increment rotation noise per radian turned (rad/rad)
    odom_sigma_rot_per_rad: float = 0.02
    # VLoc translation sigma when a VLoc pose comes without a covariance (m)
    vloc_sigma_trans: float = 0.05
    # VLoc rotation sigma when a VLoc pose comes without a covariance (degrees)
    vloc_sigma_rot_deg: float = 2.0
    # robust kernel on accepted VLoc priors
    robust_kernel: Literal["huber", "cauchy", "none"] = "cauchy"
    # robust kernel width (whitened units, sigmas)
    robust_k: float = 2.5
    # chi-square gate of a VLoc pose against the prediction (6 dof, p = 0.999); 0 = no gate
    gate_chi2: float = 22.46
    # agreeing VLoc poses needed to initialise (1 = the first one)
    init_votes: int = 2
    # initialisation votes agree when their T_map_odom lie within this (m) ...
    init_max_trans_m: float = 0.5
    # ... and this (degrees)
    init_max_rot_deg: float = 10.0
    # initialisation votes must be captured within this of the newest (s) ...
    init_window_s: float = 5.0
    # ... or, if older (a slow first fix), the odometry between them travelled less than this (m) ...
    init_window_m: float = 2.5
    # ... and turned less than this in all (degrees)
    init_window_deg: float = 45.0
    # consecutive agreeing gated rejections that re-initialise the filter (0 = never)
    reinit_after_rejects: int = 5
    # at most one marginal covariance per this much sensor time (s)
    covariance_period_s: float = 1.0
    # odometry kept for late VLoc poses (s, >= lag_s): a vote captured longer ago is refused as too old
    odom_buffer_s: float = 60.0
    # a VLoc pose up to this much newer than the newest odometry is extrapolated (s)
    max_future_s: float = 0.05
    # a VLoc pose older than the window is carried to it by odometry that moved less than this since (m; 0 = off) ...
    late_max_travel_m: float = 5.0
    # ... and turned less than this (degrees)
    late_max_turn_deg: float = 360.0
    # odometry heading drift its random-walk noise misses, 1 sigma per metre since the last accepted VLoc pose (deg/m)
    odom_drift_yaw_deg_per_m: float = 0.5
    # ... and its scale drift, along the net displacement since that pose (m per m, 1 sigma)
    odom_drift_trans_per_m: float = 0.02

    def __post_init__(self) -> None:
        positive = (
            "keyframe_period_s",
            "keyframe_dist_m",
            "keyframe_angle_deg",
            "lag_s",
            "odom_sigma_trans_floor",
            "odom_sigma_rot_floor_deg",
            "vloc_sigma_trans",
            "vloc_sigma_rot_deg",
            "robust_k",
            "init_max_trans_m",
            "init_max_rot_deg",
            "init_window_s",
            "init_window_m",
            "init_window_deg",
            "covariance_period_s",
            "odom_buffer_s",
        )
        for name in positive:
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a finite number > 0, got {v}")
        for name in (
            "odom_sigma_trans_per_m",
            "odom_sigma_rot_per_m_deg",
            "odom_sigma_rot_per_rad",
            "gate_chi2",
            "max_future_s",
            "late_max_travel_m",
            "late_max_turn_deg",
            "odom_drift_yaw_deg_per_m",
            "odom_drift_trans_per_m",
        ):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"{name} must be a finite number >= 0, got {v}")
        if self.robust_kernel not in ("huber", "cauchy", "none"):
            raise ValueError(
                f"robust_kernel must be huber, cauchy or none, got {self.robust_kernel!r}"
            )
        if self.init_votes < 1:
            raise ValueError(f"init_votes must be >= 1, got {self.init_votes}")
        if self.reinit_after_rejects < 0:
            raise ValueError(f"reinit_after_rejects must be >= 0, got {self.reinit_after_rejects}")
        if self.lag_s < 2 * self.keyframe_period_s:
            raise ValueError(
                f"lag_s ({self.lag_s}) must be >= 2 * keyframe_period_s ({self.keyframe_period_s})"
            )
        if self.odom_buffer_s < self.lag_s:
            raise ValueError(
                f"odom_buffer_s ({self.odom_buffer_s}) must be >= lag_s ({self.lag_s})"
            )

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
