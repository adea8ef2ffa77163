"""drift_covariance: where a heading bias and a scale error put the odometry's error."""

from __future__ import annotations

import itertools
import math

import numpy as np

from litevloc.base.geometry import make_T, so3_exp
from litevloc.pipelines.fusion.drift import PathMoments, drift_covariance

B, K = 0.01, 0.02  # heading bias rad/m, scale error m/m (1 sigma)


def _moments(points: list[np.ndarray]) -> PathMoments:
    m = PathMoments.zero()
    for a, b in itertools.pairwise(points):
        m = m.step(a, b)
    return m


def _line(a: tuple[float, float], b: tuple[float, float], n: int = 100) -> list[np.ndarray]:
    return [np.array([x, y, 0.0]) for x, y in np.linspace(a, b, n + 1)]


def _sigmas(points: list[np.ndarray], heading_rad: float) -> np.ndarray:
    T = make_T(so3_exp(np.array([0.0, 0.0, heading_rad])), points[-1])
    return np.sqrt(np.diag(drift_covariance(_moments(points), points[0], T, B, K)))


def test_a_straight_drive_drifts_sideways_with_the_square_of_the_path() -> None:
    s = _sigmas(_line((0, 0), (10, 0)), 0.0)  # (rot x y z, trans x y z), body frame
    np.testing.assert_allclose(s, [0, 0, B * 10, K * 10, B * 10**2 / 2, 0], atol=1e-9)


def test_out_and_back_keeps_the_heading_error_and_loses_the_scale_error() -> None:
    s = _sigmas(_line((0, 0), (10, 0)) + _line((10, 0), (0, 0))[1:], math.pi)
    np.testing.assert_allclose(s, [0, 0, B * 20, 0, B * 20**2 / 4, 0], atol=1e-9)


def test_after_a_turn_the_error_made_before_it_lies_along_the_new_heading() -> None:
    """10 m along x, then 10 m along y (heading +y): the first leg's sideways error (y in the
    odometry frame, 0.5 m) is now along-track, the second leg's (-x: 0.5 m from its own bias
    plus 1.0 m from the first leg's 0.1 rad carried over it) is sideways."""
    pts = _line((0, 0), (10, 0)) + _line((10, 0), (10, 10))[1:]
    T = make_T(so3_exp(np.array([0.0, 0.0, math.pi / 2])), pts[-1])
    C = drift_covariance(_moments(pts), pts[0], T, B, K)
    # heading bias: 0.2 rad, 0.5 m along-track, 1.5 m to the left (body y), all from one bias
    heading = B * np.array([0, 0, 20, 50, 150, 0])
    scale = K * np.array([0, 0, 0, 10, -10, 0])  # the net displacement (10, 10) in the body frame
    np.testing.assert_allclose(C, np.outer(heading, heading) + np.outer(scale, scale), atol=1e-9)


def test_the_moments_between_two_points_of_a_path_are_their_difference() -> None:
    pts = _line((0, 0), (10, 0)) + _line((10, 0), (10, 10))[1:]
    whole, prefix = _moments(pts), _moments(pts[:101])
    part = whole.since(prefix)
    direct = _moments(pts[100:])
    assert math.isclose(part.length_m, direct.length_m)
    np.testing.assert_allclose(part.first_moment, direct.first_moment, atol=1e-9)
    assert prefix.since(whole).length_m == 0.0  # no path after a later point
