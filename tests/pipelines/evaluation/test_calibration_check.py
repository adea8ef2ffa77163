"""The 95 % ellipsoid test used to check covariance calibration."""

from __future__ import annotations

import numpy as np
import pytest

from litevloc.base.geometry import make_T, so3_exp
from litevloc.pipelines.evaluation.reloc import inside_95_ellipsoids


def test_monte_carlo_share_is_95_percent() -> None:
    rng = np.random.default_rng(0)
    cov = np.diag([0.01**2, 0.02**2, 0.005**2, 0.002**2, 0.004**2, 0.001**2])
    L = np.linalg.cholesky(cov)
    T = make_T(so3_exp(np.array([0.3, -0.2, 1.0])), np.array([1.0, 2.0, 0.5]))
    inside = []
    for _ in range(2000):
        e = L @ rng.normal(size=6)
        inside.append(inside_95_ellipsoids(T, T @ make_T(so3_exp(e[3:]), e[:3]), cov))
    share = np.mean(inside, axis=0)
    assert np.all(np.abs(share - 0.95) < 0.02), share


def test_error_is_taken_in_the_camera_frame() -> None:
    """A 5 cm error along the camera's x is inside a covariance tight in y/z but loose in x."""
    cov = np.diag([0.05**2, 1e-6, 1e-6, 1e-4, 1e-4, 1e-4])
    T = make_T(so3_exp(np.array([0.0, 0.0, np.pi / 2])), np.zeros(3))  # camera x = map y
    assert inside_95_ellipsoids(T, T @ make_T(np.eye(3), np.array([0.05, 0, 0])), cov) == (True, True)
    assert inside_95_ellipsoids(T, make_T(T[:3, :3], np.array([0.05, 0, 0])), cov)[0] is False
    with pytest.raises(ValueError):
        inside_95_ellipsoids(T, T, np.eye(3))
