"""The prior a query starts from, its gate, and the refusal kinds with their reason texts."""

from __future__ import annotations

import numpy as np
import pytest

from litevloc.base.params.localization import LocalizationParams
from litevloc.pipelines.localization import prior as pg
from litevloc.pipelines.localization.prior import Prior
from litevloc.pipelines.localization.refusals import QueryRefusal, refusal_text

P = LocalizationParams()


def test_a_prior_checks_its_covariance() -> None:
    assert Prior(np.eye(4), cov=np.eye(3) * 0.01).cov.shape == (3, 3)  # type: ignore[union-attr]
    with pytest.raises(ValueError, match="prior_cov"):
        Prior(np.eye(4), cov=np.eye(2))
    with pytest.raises(ValueError, match="prior_cov"):
        Prior(np.eye(4), cov=np.full((3, 3), np.nan))


def test_the_gate_grows_with_the_odometry_for_a_fused_prior_and_with_speed_for_the_last_pose() -> None:
    assert pg.growth_m(P, 5.0, fused=False) == pytest.approx(P.prior_gate.rate_mps * 5.0)
    assert pg.growth_m(P, 5.0, fused=True) == pytest.approx(P.prior_gate.rate_fused_mps * 5.0)
    # at rest (no odometry travel) a fused prior keeps its gate
    assert pg.growth_m(P, 5.0, fused=True, travel_m=0.0) == 0.0
    assert pg.gate_m(P, 0.1, fused=True) == pytest.approx(P.prior_gate.fused_m + 0.1)
    assert pg.gate_m(P, 0.1, fused=False) == pytest.approx(P.prior_gate.radius_m + 0.1)
    assert pg.fresh(P, 0.0) and not pg.fresh(P, 10.0)


def test_the_covariance_narrows_the_gate_along_the_direction_it_knows() -> None:
    T = np.eye(4)
    T[0, 3] = 0.5
    tight_x = np.diag([0.05**2, 0.3**2, 0.3**2])
    assert pg.gate_toward(P, T, np.eye(4), 1.0, tight_x) == pytest.approx(P.prior_gate.fused_m + 3 * 0.05)
    assert pg.gate_toward(P, T, np.eye(4), 1.0, None) == 1.0
    assert not pg.within_gate(P, T, np.eye(4), 1.0, tight_x) and pg.within_gate(P, T, np.eye(4), 1.0)


def test_each_refusal_kind_says_its_reason_with_its_numbers() -> None:
    """The texts logs, diagnostics and benchmarks print, word for word."""
    assert refusal_text(QueryRefusal.NONE) == "ok"
    assert refusal_text(QueryRefusal.NO_NODE_NEAR_PRIOR) == "no map node near the prior"
    assert refusal_text(QueryRefusal.NO_CANDIDATE) == "not localized: no candidate verified"
    assert refusal_text(QueryRefusal.NO_VPR_CANDIDATE) == "not localized: no VPR candidate verified"
    assert refusal_text(QueryRefusal.UNCONFIRMED, node=7) == (
        "not localized: no verified pose was confirmed by a second keyframe (last: node 7)")
    assert refusal_text(QueryRefusal.HELD, mode="GL", detail="why") == (
        "not localized: GL pose held until a later frame repeats it (why)")
    assert refusal_text(QueryRefusal.HELD_ELSEWHERE, dt_m=1.234, dr_deg=12.6, gate_m=0.5, dt_s=2.0) == (
        "not localized: 1.23 m / 13 deg from the prior, outside its gate (0.50 m), while a pose inside it "
        "held 2.00 s before awaits its repeat")
    assert refusal_text(QueryRefusal.AMBIGUOUS, detail="ambiguous: x") == "not localized: ambiguous: x"
