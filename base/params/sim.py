"""Simulator parameters (robot, head camera, sensor rates, drift and imaging effects): the
config section `sim`, used by `litevloc.sim`."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from litevloc.base.geometry import PinholeIntrinsics, make_T, so3_exp
from litevloc.base.params.drift import R_BASE_OPTICAL, DriftParams
from litevloc.base.settings import Settings, section, setting


@dataclass(frozen=True)
class RealismParams(Settings):
    """Ranges of the imaging effects (all seeded). `enabled: false` gives ideal images."""

    enabled: bool = setting(True, "simulate the imaging effects (false: ideal images and depth)")
    brightness: tuple[float, float] = setting(
        (0.75, 1.2), "range [lo, hi] of the per-sequence brightness gain", low=0, low_open=True)
    gamma: tuple[float, float] = setting(
        (0.85, 1.2), "range [lo, hi] of the per-sequence gamma", low=0, low_open=True)
    color_cast: float = setting(0.08, "largest relative per-channel gain deviation (colour cast)", low=0)
    blur_sigma: tuple[float, float] = setting(
        (0.0, 0.7), "range [lo, hi] of the per-sequence Gaussian blur", unit="px", low=0)
    noise_sigma: float = setting(2.5, "per-pixel Gaussian image noise", unit="grey levels", low=0)
    depth_noise_per_m2: float = setting(0.002, "depth noise sigma = this x z^2", unit="1/m", low=0)
    depth_min: float = setting(0.2, "simulated depth nearer than this is invalid", unit="m", low=0)
    depth_max: float = setting(10.0, "simulated depth farther than this is invalid (above depth_min)", unit="m", low=0)
    edge_hole_prob: float = setting(0.6, "chance that a pixel at a depth edge is a hole", low=0, high=1)
    dropout: float = setting(0.005, "share of depth pixels randomly invalid", low=0, high=1)

    def check_relations(self) -> None:
        for name in ("brightness", "gamma", "blur_sigma"):
            lo, hi = getattr(self, name)
            if not lo <= hi:
                raise ValueError(f"{name} must be [lo, hi] with 0 <= lo <= hi, got {(lo, hi)}")
        if not self.depth_min < self.depth_max:
            raise ValueError(f"need 0 <= depth_min < depth_max, got {self.depth_min}, {self.depth_max}")


@dataclass(frozen=True)
class SimParams(Settings):
    """Robot, camera and sensor-rate parameters of the simulator."""

    width: int = setting(320, "simulated image width", unit="px", low=16, high=4096)
    height: int = setting(240, "simulated image height", unit="px", low=16, high=4096)
    hfov_deg: float = setting(72.0, "horizontal field of view of the simulated camera", unit="deg", low=20, high=150)
    camera_height: float = setting(0.5, "camera height above the floor", unit="m", low=0.05, high=2)
    camera_forward: float = setting(0.25, "camera ahead of the robot's centre", unit="m", low=-math.inf)
    camera_tilt_deg: float = setting(5.0, "camera pitch down", unit="deg", low=-30, high=30)
    camera_rate_hz: float = setting(15.0, "simulated camera frame rate", unit="Hz", low=0, low_open=True, high=120)
    odometry_rate_hz: float = setting(
        200.0, "wheel odometry rate (at least camera_rate_hz)", unit="Hz", low=0, low_open=True, high=2000)
    robot_radius: float = setting(0.3, "simulated robot radius", unit="m", low=0, low_open=True)
    max_speed: float = setting(1.0, "commanded speeds are clipped to this", unit="m/s", low=0, low_open=True)
    max_omega: float = setting(1.5, "commanded turn rates are clipped to this", unit="rad/s", low=0, low_open=True)
    cruise_speed: float = setting(
        0.5, "the scripted passes' waypoint follower drives at this speed (at most max_speed)", unit="m/s", low=0,
        low_open=True)
    cruise_omega: float = setting(
        0.6, "the scripted passes' waypoint follower turns at this rate (at most max_omega)", unit="rad/s", low=0,
        low_open=True)
    bob_deg: float = setting(0.6, "camera roll/pitch bobbing amplitude at max_speed", unit="deg", low=0)
    bob_height: float = setting(0.01, "camera height bobbing amplitude at max_speed", unit="m", low=0)
    gait_hz: float = setting(2.0, "camera bobbing frequency", unit="Hz", low=0, low_open=True)
    drift: DriftParams = section(DriftParams, "the wheel odometry's drift")
    realism: RealismParams = section(RealismParams, "the imaging effects")

    def check_relations(self) -> None:
        if self.odometry_rate_hz < self.camera_rate_hz:
            raise ValueError("odometry_rate_hz must be >= camera_rate_hz")
        if self.cruise_speed > self.max_speed or self.cruise_omega > self.max_omega:
            raise ValueError("cruise_speed/cruise_omega must not exceed max_speed/max_omega")

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
