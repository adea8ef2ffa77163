"""Simulator parameters (robot, head camera, sensor rates, drift and imaging effects): the
config section `sim`, used by `litevloc.sim`."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from litevloc.base.geometry import PinholeIntrinsics, make_T, so3_exp
from litevloc.base.params.drift import R_BASE_OPTICAL, DriftParams


@dataclass(frozen=True)
class RealismParams:
    """Ranges of the imaging effects (all seeded). `enabled: false` gives ideal images."""

    # false: ideal images and depth
    enabled: bool = True
    # range of the per-sequence brightness gain
    brightness: tuple[float, float] = (0.75, 1.2)
    # range of the per-sequence gamma
    gamma: tuple[float, float] = (0.85, 1.2)
    # largest relative per-channel gain deviation (colour cast)
    color_cast: float = 0.08
    # range of the per-sequence Gaussian blur (pixels)
    blur_sigma: tuple[float, float] = (0.0, 0.7)
    # per-pixel Gaussian noise (grey levels)
    noise_sigma: float = 2.5
    # depth noise sigma = this x z^2 (1/m)
    depth_noise_per_m2: float = 0.002
    # nearer depth is invalid (m)
    depth_min: float = 0.2
    # farther depth is invalid (m)
    depth_max: float = 10.0
    # chance that a pixel at a depth edge is a hole
    edge_hole_prob: float = 0.6
    # share of depth pixels randomly invalid
    dropout: float = 0.005

    def __post_init__(self) -> None:
        for name in ("brightness", "gamma", "blur_sigma"):
            lo, hi = getattr(self, name)
            if not (0 <= lo <= hi) or not np.isfinite(hi):
                raise ValueError(f"{name} must be [lo, hi] with 0 <= lo <= hi, got {(lo, hi)}")
        if self.brightness[0] <= 0 or self.gamma[0] <= 0:
            raise ValueError("brightness and gamma must be > 0")
        for name in (
            "color_cast",
            "noise_sigma",
            "depth_noise_per_m2",
            "edge_hole_prob",
            "dropout",
        ):
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise ValueError(f"{name} must be >= 0, got {v}")
        if self.edge_hole_prob > 1 or self.dropout > 1:
            raise ValueError("edge_hole_prob and dropout are probabilities in [0, 1]")
        if not (0 <= self.depth_min < self.depth_max):
            raise ValueError(
                f"need 0 <= depth_min < depth_max, got {self.depth_min}, {self.depth_max}"
            )


@dataclass(frozen=True)
class SimParams:
    """Robot, camera and sensor-rate parameters of the simulator."""

    # image width (pixels)
    width: int = 320
    # image height (pixels)
    height: int = 240
    # horizontal field of view (degrees)
    hfov_deg: float = 72.0
    # camera height above the floor (m)
    camera_height: float = 0.5
    # camera ahead of the robot's centre (m)
    camera_forward: float = 0.25
    # camera pitch down (degrees)
    camera_tilt_deg: float = 5.0
    # camera frame rate (Hz)
    camera_rate_hz: float = 15.0
    # wheel odometry rate (Hz)
    odometry_rate_hz: float = 200.0
    # robot radius (m)
    robot_radius: float = 0.3
    # commanded speeds are clipped to this (m/s)
    max_speed: float = 1.0
    # commanded turn rates are clipped to this (rad/s)
    max_omega: float = 1.5
    # the scripted passes' waypoint follower drives at this speed (m/s)
    cruise_speed: float = 0.5
    # ... and turns at this rate (rad/s)
    cruise_omega: float = 0.6
    # camera roll/pitch bobbing amplitude at max_speed (degrees)
    bob_deg: float = 0.6
    # camera height bobbing amplitude at max_speed (m)
    bob_height: float = 0.01
    # bobbing frequency (Hz)
    gait_hz: float = 2.0
    # the wheel odometry's drift
    drift: DriftParams = field(default_factory=DriftParams)
    # the imaging effects
    realism: RealismParams = field(default_factory=RealismParams)

    def __post_init__(self) -> None:
        if not (16 <= self.width <= 4096 and 16 <= self.height <= 4096):
            raise ValueError(f"image size must be in [16, 4096], got {self.width}x{self.height}")
        if not (20 <= self.hfov_deg <= 150):
            raise ValueError(f"hfov_deg must be in [20, 150], got {self.hfov_deg}")
        if not (0.05 <= self.camera_height <= 2.0):
            raise ValueError(f"camera_height must be in [0.05, 2] m, got {self.camera_height}")
        if not (-30 <= self.camera_tilt_deg <= 30):
            raise ValueError(f"camera_tilt_deg must be in [-30, 30], got {self.camera_tilt_deg}")
        if not (0 < self.camera_rate_hz <= 120) or not (0 < self.odometry_rate_hz <= 2000):
            raise ValueError("camera_rate_hz must be in (0, 120] and odometry_rate_hz in (0, 2000]")
        if self.odometry_rate_hz < self.camera_rate_hz:
            raise ValueError("odometry_rate_hz must be >= camera_rate_hz")
        for name in (
            "robot_radius",
            "max_speed",
            "max_omega",
            "cruise_speed",
            "cruise_omega",
            "gait_hz",
        ):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0")
        if self.cruise_speed > self.max_speed or self.cruise_omega > self.max_omega:
            raise ValueError("cruise_speed/cruise_omega must not exceed max_speed/max_omega")
        if self.bob_deg < 0 or self.bob_height < 0:
            raise ValueError("bob_deg and bob_height must be >= 0")

    @property
    def intrinsics(self) -> PinholeIntrinsics:
        fx = (self.width / 2) / np.tan(np.radians(self.hfov_deg) / 2)
        return PinholeIntrinsics(
            fx, fx, (self.width - 1) / 2, (self.height - 1) / 2, self.width, self.height
        )

    @property
    def T_base_camera(self) -> NDArray[np.float64]:
        """4x4 pose of the camera optical frame in base_link (tilted down by camera_tilt_deg)."""
        tilt = np.radians(self.camera_tilt_deg)
        R_pitch = so3_exp(np.array([0.0, tilt, 0.0]))  # +pitch about base y tilts x (forward) down
        return make_T(
            R_pitch @ R_BASE_OPTICAL, np.array([self.camera_forward, 0.0, self.camera_height])
        )
