"""base.geometry helpers not covered through the pipelines' tests."""

from __future__ import annotations

import numpy as np

from litevloc.base.geometry import undistort_normalized


def test_undistort_normalized_inverts_the_radial_model() -> None:
    x = np.random.default_rng(1).uniform(-0.6, 0.6, (50, 2))
    k1, k2 = -0.07, 0.02
    r2 = np.sum(x * x, axis=1, keepdims=True)
    xd = x * (1 + k1 * r2 + k2 * r2 * r2)
    np.testing.assert_allclose(undistort_normalized(xd, k1, k2), x, atol=1e-9)
    np.testing.assert_array_equal(undistort_normalized(xd, 0.0, 0.0), xd)  # no model: unchanged
    assert np.abs(xd - x).max() > 1e-3  # the model does move these points
