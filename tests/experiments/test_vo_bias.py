"""The visual-edge bias bench's arithmetic (experiments/vo_bias.py); the front end itself is
tested in tests/pipelines/slam."""

from __future__ import annotations

import numpy as np
import pytest

from litevloc.base.geometry import make_T
from litevloc.experiments.vo_bias import along_motion_error, edge_pairs, subset_mask, summary


def _line(step_m: float, n: int) -> np.ndarray:
    return np.stack([make_T(np.eye(3), np.array([0.0, 0.0, step_m * k])) for k in range(n)])


def test_pairs_are_a_step_apart_and_a_standing_robot_gives_none() -> None:
    pairs = edge_pairs(_line(0.1, 400), 0.29, 5)
    assert len(pairs) == 5 and all(j - i == 3 for i, j in pairs)
    assert len({i for i, _ in pairs}) == 5  # spread over the pass, not one spot
    assert edge_pairs(_line(0.0, 400), 0.3, 5) == []


def test_along_motion_error_is_signed_along_the_true_motion() -> None:
    T = make_T(np.eye(3), np.array([0.0, 0.1, 0.3]))
    long = make_T(np.eye(3), 1.02 * T[:3, 3])
    assert along_motion_error(long, T) == pytest.approx(0.02 * np.linalg.norm(T[:3, 3]))
    sideways = make_T(np.eye(3), T[:3, 3] + np.array([0.01, 0.0, 0.0]))
    assert along_motion_error(sideways, T) == pytest.approx(0.0, abs=1e-12)


def test_subsets_split_floor_from_the_rest() -> None:
    h = np.array([0.0, 0.02, -0.01, 0.05, 0.5, np.nan])
    assert subset_mask(h, "floor").tolist() == [True, True, True, False, False, False]
    assert subset_mask(h, "off-floor").tolist() == [False, False, False, False, True, False]
    assert subset_mask(h, "all").tolist() == [True] * 5 + [False]
    with pytest.raises(ValueError, match="unknown subset"):
        subset_mask(h, "walls")


def test_summary_keeps_gross_errors_apart_and_bands_the_disagreement() -> None:
    errs = [{"all": 0.003, "floor": 0.006, "off-floor": -0.002}] * 9 + [{"all": -0.25, "floor": np.nan,
                                                                           "off-floor": 0.001}]
    rng = np.random.default_rng(0)
    z = rng.uniform(0.5, 6.0, 400)
    h = np.where(np.arange(400) % 2 == 0, 0.0, 1.0)
    d = np.column_stack([z, np.where(h == 0, -0.003 * z, 0.0), h])
    s = summary(errs, [0.3] * 10, d)
    assert s["all"]["gross"] == 1 and s["all"]["along_error_median_mm"] == pytest.approx(3.0)
    assert s["all"]["along_error_median_pct"] == pytest.approx(1.0)
    assert s["all"]["along_error_per_m_pct"] == pytest.approx(1.0)  # the gross one left out
    assert s["floor"]["edges"] == 9
    floor = [r for r in s["depth_disagreement"] if r["surface"] == "floor"]
    assert floor and all(r["median_pct"] == pytest.approx(-0.3) for r in floor)
    assert all(r["median_mm"] == 0.0 for r in s["depth_disagreement"] if r["surface"] == "off-floor")
