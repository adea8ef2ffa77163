"""The prior gate's radius toward a pose, narrowed by the prior's position covariance.

A fused prior carries fusion's 3x3 camera position covariance (m^2, map frame). Toward a
candidate pose, the gate is the age gate (start + drift rate x age) or, where the covariance
says the prior is better known along that direction, its start + k sigmas along it: a wrong
copy of a repeated texture one period away along the optical axis then falls outside.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray


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
