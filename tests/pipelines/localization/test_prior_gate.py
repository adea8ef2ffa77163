"""The prior gate's radius narrowed by a position covariance (pure functions)."""

from __future__ import annotations

import numpy as np
import pytest

from litevloc.pipelines.localization.prior import narrowed_gate, sigma_along


def test_sigma_along_a_direction_of_any_length() -> None:
    cov = np.diag([0.04, 0.01, 0.0025])  # sigmas 0.2, 0.1, 0.05 m
    assert sigma_along(cov, np.array([3.0, 0, 0])) == pytest.approx(0.2)
    assert sigma_along(cov, np.array([0, 0, -0.1])) == pytest.approx(0.05)
    assert sigma_along(cov, np.array([1.0, 1.0, 0])) == pytest.approx(np.sqrt((0.04 + 0.01) / 2))
    assert sigma_along(cov, np.zeros(3)) == 0.0


def test_narrowed_gate_is_never_wider_than_the_age_gate() -> None:
    assert narrowed_gate(0.85, 0.25, 3.0, 0.02) == pytest.approx(0.31)  # well known: narrowed
    assert narrowed_gate(0.85, 0.25, 3.0, 1.0) == pytest.approx(0.85)  # poorly known: the age gate
    assert narrowed_gate(0.85, 0.25, 0.0, 0.02) == pytest.approx(0.85)  # off
