"""The prior a localization query starts from, and the prior gate around it.

A prior is the fused pose at the frame's stamp (`fused`: odometry carried it since fusion's last
VLoc fix) or the last accepted VLoc pose. Its gate is the region a pose verified from it must lie
in: a base radius (fused or last-pose) plus how far the prior may have wandered since its fix
(`growth_m`), narrowed toward a pose where fusion's position covariance says the prior is better
known along that direction (`gate_toward`, `narrowed_gate`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from litevloc.base.geometry import relative_pose_error
from litevloc.base.params.localization import LocalizationParams


@dataclass(frozen=True, eq=False)
class Prior:
    """`T_map_camera` 4x4 (metres) at the query's stamp, `age_s` seconds past its last fix;
    `fused`: fusion's pose (its gate grows at the odometry's drift rate) rather than the last
    VLoc pose (the robot's top speed); `cov`: fusion's 3x3 camera position covariance (m^2, map
    frame) or None; `travel_m`: the odometry's path since the fix (metres) or None where unknown."""

    T_map_camera: NDArray[np.float64]
    age_s: float = 0.0
    fused: bool = True
    cov: NDArray[np.float64] | None = None
    travel_m: float | None = None

    def __post_init__(self) -> None:
        if self.cov is not None:
            cov = np.asarray(self.cov, np.float64)
            if cov.shape != (3, 3) or not np.all(np.isfinite(cov)):
                raise ValueError(f"prior_cov must be a finite 3x3 covariance (m^2), got shape {cov.shape}")
            object.__setattr__(self, "cov", cov)


def sigma_along(cov: NDArray[np.floating], direction: NDArray[np.floating]) -> float:
    """Standard deviation (m) of a position with 3x3 covariance `cov` (m^2) along `direction`
    (3,), any length; 0 for a zero direction."""
    d = np.asarray(direction, np.float64).reshape(3)
    n = float(np.linalg.norm(d))
    if n == 0.0:
        return 0.0
    u = d / n
    return float(np.sqrt(max(float(u @ np.asarray(cov, np.float64) @ u), 0.0)))


def narrowed_gate(gate_m: float, start_m: float, sigmas: float, sigma_m: float) -> float:
    """The gate radius (m): `gate_m`, or `start_m` + `sigmas` x `sigma_m` where that is smaller
    (`sigmas` <= 0: no narrowing)."""
    return gate_m if sigmas <= 0 else min(gate_m, start_m + sigmas * sigma_m)


def growth_m(p: LocalizationParams, age_s: float, fused: bool, travel_m: float | None = None) -> float:
    """How far the prior may have wandered in `age_s` (m): odometry drift for a fused prior (no
    more than `prior_gate.drift_fused` of the odometry's path `travel_m` since the fix where that
    is known: a robot at rest keeps its prior), the robot's top speed for the last VLoc pose."""
    if not fused:
        return p.prior_gate.rate_mps * max(age_s, 0.0)
    growth = p.prior_gate.rate_fused_mps * max(age_s, 0.0)
    return growth if travel_m is None else min(growth, p.prior_gate.drift_fused * max(travel_m, 0.0))


def fresh(p: LocalizationParams, growth: float) -> bool:
    """A prior fresh enough to stand in for a second keyframe (see `confirm_skip_*`)."""
    return growth <= p.prior_gate.rate_mps * p.confirm.skip_max_age_s


def gate_m(p: LocalizationParams, growth: float, fused: bool) -> float:
    """The prior gate's radius (m): its base (fused or last-pose prior) + the growth."""
    return (p.prior_gate.fused_m if fused else p.prior_gate.radius_m) + growth


def gate_toward(p: LocalizationParams, T: NDArray[np.float64], prior: NDArray[np.float64], radius_m: float,
                cov: NDArray[np.float64] | None) -> float:
    """The prior gate's radius (m) toward the pose `T`: `radius_m`, or less where fusion's 3x3
    position covariance `cov` (m^2, map frame) of a fused prior says it is better known along
    that direction: its start + `prior_gate.sigmas` sigmas."""
    d = np.asarray(T, np.float64)[:3, 3] - np.asarray(prior, np.float64)[:3, 3]
    if cov is None or not np.any(d):
        return radius_m
    return narrowed_gate(radius_m, p.prior_gate.fused_m, p.prior_gate.sigmas, sigma_along(cov, d))


def within_gate(p: LocalizationParams, T: NDArray[np.float64], prior: NDArray[np.float64], radius_m: float,
                cov: NDArray[np.float64] | None = None) -> bool:
    """The prior gate: within `gate_toward` and `prior_gate.deg`."""
    dt, dr = relative_pose_error(T, prior)
    return bool(dt <= gate_toward(p, T, prior, radius_m, cov) and dr <= p.prior_gate.deg)
