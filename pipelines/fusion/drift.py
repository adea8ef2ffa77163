"""The odometry's systematic drift since the last fix, as a covariance of the base pose.

A constant heading-rate bias `b` (radians per metre driven) turns every later step of the
path `p(s)`, `s` in `[0, L]` metres from the fix: at its end the heading is `b L` off and the
position `b z x integral_0^L (p(L) - p(s)) ds` (`z` up): a straight drive `b L^2 / 2` sideways,
a drive out and back along the same line `b L^2 / 4`, and after a turn the error made before it
lies along the new heading, not across it. A scale error `k` moves the position by
`k (p(L) - p(0))`, along the net displacement. Each is one direction in the odometry frame, known
from the path; only its size (the bias) is unknown, so the covariance is rank one per source.

`PathMoments` keeps the two sums this needs, added keyframe by keyframe and differenced between
two keyframes, so the drift since any fix costs O(1) per keyframe and per query.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]

__all__ = ["PathMoments", "drift_covariance"]

_UP = np.array([0.0, 0.0, 1.0])


@dataclass(frozen=True)
class PathMoments:
    """Running sums over a piecewise-linear path in the odometry frame.

    `length_m`: metres driven. `first_moment`: (3,) the integral of the position over the
    path, `sum(midpoint * step length)`, m^2. Both are cumulative from an arbitrary start;
    `since(earlier)` gives the sums between two points of the same path.
    """

    length_m: float
    first_moment: F64

    @staticmethod
    def zero() -> PathMoments:
        return PathMoments(0.0, np.zeros(3))

    def step(self, p_from: F64, p_to: F64) -> PathMoments:
        """The sums after one more straight step from `p_from` to `p_to` (3,), metres."""
        ds = float(np.linalg.norm(p_to - p_from))
        return PathMoments(self.length_m + ds, self.first_moment + 0.5 * (p_from + p_to) * ds)

    def since(self, earlier: PathMoments) -> PathMoments:
        """The sums over the part of the path after `earlier` (a prefix of this one; zero where
        `earlier` is not shorter)."""
        if self.length_m <= earlier.length_m:
            return PathMoments.zero()
        return PathMoments(self.length_m - earlier.length_m, self.first_moment - earlier.first_moment)


def drift_covariance(
    path: PathMoments,
    p_start: F64,
    T_odom_base: F64,
    yaw_rate_sigma: float,
    scale_sigma: float,
) -> F64:
    """6x6 covariance, GTSAM order (rot, trans), body-frame perturbation of `T_odom_base` (4x4,
    the pose at the path's end), of the drift over `path` (the sums from the fix at `p_start`
    (3,), odometry frame, to the path's end at `T_odom_base`'s position).

    `yaw_rate_sigma`: heading bias, rad per metre (1 sigma); `scale_sigma`: scale error, m per
    m (1 sigma). Rank two: the heading bias moves heading and position together (correlated),
    the scale error moves the position along the net displacement. Zero for an empty path (the
    end is not after the fix).
    """
    if path.length_m <= 0:
        return np.zeros((6, 6))
    R = T_odom_base[:3, :3]
    p_end = T_odom_base[:3, 3]
    L = path.length_m
    lever = np.cross(_UP, L * p_end - path.first_moment)  # d(position)/d(heading bias), odometry frame
    g_heading = yaw_rate_sigma * np.concatenate([R.T @ (_UP * L), R.T @ lever])
    g_scale = scale_sigma * np.concatenate([np.zeros(3), R.T @ (p_end - p_start)])
    return np.outer(g_heading, g_heading) + np.outer(g_scale, g_scale)
