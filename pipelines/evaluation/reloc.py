"""Relocalization metrics in the style of the map-free relocalization benchmark.

Per query: the pose relative to its reference keyframe is estimated (or not); errors are
the translation distance (m) and rotation angle (deg) to the ground-truth relative pose.
Reported per method: % estimated, median and max errors over estimated queries, and
precision at [5 cm, 5 deg], [25 cm, 5 deg], [1 m, 10 deg] — counted over ALL queries
(a query without an estimate is a miss), and over estimated ones only.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from litevloc.base.geometry import invert, so3_log

CHI2_95_3DOF = 7.814727903251178  # scipy.stats.chi2.ppf(0.95, 3)

THRESHOLDS: tuple[tuple[float, float], ...] = ((0.05, 5.0), (0.25, 5.0), (1.0, 10.0))


@dataclass(frozen=True)
class RelocMetrics:
    """Summary of one method over a query set."""

    queries: int
    estimated: int
    pct_estimated: float
    median_trans_m: float
    median_rot_deg: float
    max_trans_m: float
    max_rot_deg: float
    precision_5cm_5deg: float
    precision_25cm_5deg: float
    precision_1m_10deg: float
    precision_estimated_25cm_5deg: float
    time_median_ms: float
    time_p90_ms: float

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


def reloc_metrics(
    trans_err_m: NDArray[np.floating], rot_err_deg: NDArray[np.floating], times_ms: NDArray[np.floating]
) -> RelocMetrics:
    """Errors are (N,) arrays with NaN where the method gave no estimate."""
    t = np.asarray(trans_err_m, dtype=np.float64)
    r = np.asarray(rot_err_deg, dtype=np.float64)
    if t.shape != r.shape or t.ndim != 1:
        raise ValueError("trans_err_m and rot_err_deg must be equal-length vectors")
    n = len(t)
    est = np.isfinite(t) & np.isfinite(r)
    k = int(est.sum())

    def within(tt: float, rr: float, over: NDArray[np.bool_]) -> float:
        ok = est & (np.nan_to_num(t, nan=np.inf) <= tt) & (np.nan_to_num(r, nan=np.inf) <= rr)
        return float(ok[over].sum() / max(int(over.sum()), 1))

    allq = np.ones(n, dtype=bool)
    nan = float("nan")
    times = np.asarray(times_ms, dtype=np.float64)
    return RelocMetrics(
        queries=n, estimated=k, pct_estimated=100.0 * k / max(n, 1),
        median_trans_m=float(np.median(t[est])) if k else nan, median_rot_deg=float(np.median(r[est])) if k else nan,
        max_trans_m=float(t[est].max()) if k else nan, max_rot_deg=float(r[est].max()) if k else nan,
        precision_5cm_5deg=within(0.05, 5.0, allq), precision_25cm_5deg=within(0.25, 5.0, allq),
        precision_1m_10deg=within(1.0, 10.0, allq), precision_estimated_25cm_5deg=within(0.25, 5.0, est),
        time_median_ms=float(np.median(times)) if len(times) else nan,
        time_p90_ms=float(np.percentile(times, 90)) if len(times) else nan,
    )


def inside_95_ellipsoids(
    T_est: NDArray[np.floating], T_gt: NDArray[np.floating], covariance: NDArray[np.floating]
) -> tuple[bool, bool]:
    """Whether the error of a pose lies inside its own 95 % ellipsoid, (position, rotation).

    The error is the right perturbation e = (t, rotvec) with T_gt = T_est @ exp(e) (the
    convention of `pipelines.pnp`); position and rotation are tested separately with their
    3x3 marginal covariances against the chi-square 95 % quantile for 3 dof.
    """
    E = invert(np.asarray(T_est, dtype=np.float64)) @ np.asarray(T_gt, dtype=np.float64)
    dt, dr = E[:3, 3], so3_log(E[:3, :3])
    C = np.asarray(covariance, dtype=np.float64)
    if C.shape != (6, 6):
        raise ValueError(f"covariance must be 6x6, got {C.shape}")
    mt = float(dt @ np.linalg.solve(C[:3, :3], dt))
    mr = float(dr @ np.linalg.solve(C[3:, 3:], dr))
    return mt <= CHI2_95_3DOF, mr <= CHI2_95_3DOF
