"""bench/fit_covariance.py: the maximum-likelihood fit of the systematic covariance terms."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from litevloc.config import load_config
from tests.bench import load_bench


def _rows(n: int, x: np.ndarray, seed: int) -> list[tuple]:
    """Errors drawn from solve covariance (0.3 cm)^2 I plus a^2 + (b theta)^2 + (c d)^2 per axis."""
    rng = np.random.default_rng(seed)
    rows = []
    for _ in range(n):
        th, d = rng.uniform(0.0, 0.6), rng.uniform(0.1, 1.5)
        Cp = np.eye(3) * 0.003**2
        s2 = 0.003**2 + x[0] ** 2 + (x[1] * th) ** 2 + (x[2] * d) ** 2
        e = rng.normal(0.0, np.sqrt(s2), 3)
        rows.append((Cp, Cp, th, d, e, e))
    return rows


def test_fit_recovers_the_growth_with_angle_and_distance_and_covers_95_percent() -> None:
    fc = load_bench("fit_covariance")
    truth = np.array([0.0, 0.08, 0.02])
    x, nll = fc.fit(_rows(400, truth, 1), 0, (1, 1, 1))
    assert abs(x[1] - truth[1]) < 0.25 * truth[1] and abs(x[2] - truth[2]) < 0.25 * truth[2], x
    held = _rows(400, truth, 2)
    assert 92.0 <= fc.coverage_pct(x, held, 0) <= 98.0
    # a model without the distance term explains the same errors worse
    _, nll_angle = fc.fit(_rows(400, truth, 1), 0, (1, 1, 0))
    assert nll < nll_angle - 10


def test_rows_are_the_recorded_covariance_less_its_systematic_terms(tmp_path: Path) -> None:
    fc = load_bench("fit_covariance")
    p = load_config("7scenes").localization.refine
    th, d = np.radians(20.0), 0.8
    vt = p.sigma_sys_t_m**2 + (p.sigma_sys_t_per_rad * th) ** 2 + (p.sigma_sys_t_per_m * d) ** 2
    vr = (np.radians(p.sigma_sys_r_deg) ** 2 + (p.sigma_sys_r_per_rad * th) ** 2
          + np.radians(p.sigma_sys_r_deg_per_m * d) ** 2)
    solve = np.diag([1e-4, 2e-4, 3e-4, 1e-5, 2e-5, 3e-5])
    C = solve + np.diag([vt] * 3 + [vr] * 3)
    frame = {"accepted": True, "covariance": C.tolist(), "view_angle_deg": 20.0, "keyframe_distance_m": d,
             "err_cam_m": [0.01, 0.0, 0.0], "err_cam_rotvec": [0.0, 0.01, 0.0]}
    f = tmp_path / "acc.json"
    f.write_text(json.dumps({"results": [{"overrides": [], "frames": [frame, {"accepted": False}]}]}))
    rows, floored = fc.load_rows(f)
    assert len(rows) == 1 and floored == 0
    np.testing.assert_allclose(rows[0][0], solve[:3, :3], atol=1e-12)
    np.testing.assert_allclose(rows[0][1], solve[3:, 3:], atol=1e-12)
    assert rows[0][2] == th and rows[0][3] == d
