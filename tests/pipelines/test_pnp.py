"""PnP + acceptance on synthetic geometry where the truth is known exactly."""

from __future__ import annotations

import numpy as np
import pytest

from litevloc.base import geometry as g
from litevloc.base.params.localization import PnpParams
from litevloc.pipelines.pnp import Refusal, solve_pnp

K = np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]])


def scene(n: int = 300, outlier_frac: float = 0.3, noise_px: float = 0.5, seed: int = 0):  # type: ignore[no-untyped-def]
    rng = np.random.default_rng(seed)
    pts_src = np.column_stack([rng.uniform(-2, 2, n), rng.uniform(-1.5, 1.5, n), rng.uniform(2, 6, n)])
    T_tgt_src = g.make_T(g.so3_exp(np.array([0.05, -0.2, 0.03])), [0.3, -0.05, 0.2])
    pix = g.project(K, g.transform_points(T_tgt_src, pts_src)) + rng.normal(0, noise_px, (n, 2))
    n_out = int(outlier_frac * n)
    pix[:n_out] = rng.uniform([0, 0], [640, 480], (n_out, 2))
    return pts_src, pix, T_tgt_src, n_out


@pytest.mark.parametrize("method", ["p3p", "ap3p", "sqpnp", "epnp", "usac_magsac"])
def test_recovers_pose_with_outliers(method: str) -> None:
    pts, pix, T_true, n_out = scene()
    res = solve_pnp(pts, pix, K, PnpParams(method=method))
    assert res.accepted, res.reason
    dt, dr = g.relative_pose_error(res.T_target_source, T_true)
    assert dt < 0.02 and dr < 0.3
    assert res.n_inliers >= 0.9 * (len(pts) - n_out)
    assert np.count_nonzero(res.inliers < n_out) <= 5  # outliers are (almost all) rejected
    assert res.covariance is not None and np.all(np.linalg.eigvalsh(res.covariance) > 0)


def test_deterministic_given_seed() -> None:
    pts, pix, _, _ = scene(outlier_frac=0.5)
    a = solve_pnp(pts, pix, K, PnpParams(seed=3))
    b = solve_pnp(pts, pix, K, PnpParams(seed=3))
    assert np.array_equal(a.T_target_source, b.T_target_source) and np.array_equal(a.inliers, b.inliers)


def test_acceptance_gates_reject() -> None:
    pts, pix, _, _ = scene(n=40, outlier_frac=0.0)
    res = solve_pnp(pts, pix, K, PnpParams(min_inliers=50))
    assert not res.accepted and "too few" in res.reason and res.refusal is Refusal.DEPTH
    pts, pix, _, _ = scene(n=60, outlier_frac=0.5)
    res = solve_pnp(pts, pix, K, PnpParams(min_inliers=40, min_inlier_ratio=0.0))
    assert not res.accepted and res.refusal is Refusal.INLIERS and 25 <= res.n_inliers < 40, res.reason
    pts, pix, _, _ = scene(n=300, outlier_frac=0.85, seed=2)
    res = solve_pnp(pts, pix, K, PnpParams(min_inliers=10, min_inlier_ratio=0.3))
    assert not res.accepted and "ratio" in res.reason and res.refusal is Refusal.INLIER_RATIO
    assert solve_pnp(*scene()[:2], K, PnpParams()).refusal is Refusal.NONE
    rng = np.random.default_rng(1)
    junk = solve_pnp(rng.uniform(1, 5, (200, 3)), rng.uniform(0, 640, (200, 2)), K, PnpParams())
    assert not junk.accepted


def test_covariance_grows_with_noise() -> None:
    pts, pix, _, _ = scene(outlier_frac=0.0, noise_px=0.3)
    pts2, pix2, _, _ = scene(outlier_frac=0.0, noise_px=1.5)
    p = PnpParams(min_sigma_trans_m=0.0, min_sigma_rot_rad=0.0, max_median_reprojection_px=3)
    c1 = solve_pnp(pts, pix, K, p).covariance
    c2 = solve_pnp(pts2, pix2, K, p).covariance
    assert c1 is not None and c2 is not None and np.trace(c2[:3, :3]) > 4 * np.trace(c1[:3, :3])


def test_bad_input() -> None:
    with pytest.raises(ValueError, match="finite"):
        solve_pnp(np.full((10, 3), np.nan), np.zeros((10, 2)), K)
    with pytest.raises(ValueError, match="pixels"):
        solve_pnp(np.zeros((10, 3)), np.zeros((9, 2)), K)


def test_result_keeps_ransacs_consensus_set_apart_from_the_rescored_inliers() -> None:
    """`ransac_inliers` is RANSAC's consensus (sorted match indices, the goal planner's support
    count), kept beside the refined pose's re-scored `inliers` and through `inverse_result`."""
    import cv2

    from litevloc.pipelines.pnp import inverse_result

    pts, pix, _, n_out = scene(n=200, outlier_frac=0.2, noise_px=2.0)
    res = solve_pnp(pts, pix, K, PnpParams(method="epnp", reprojection_px=3.0, seed=1))
    cv2.setRNGSeed(1)
    _ok, _r, _t, inl = cv2.solvePnPRansac(pts, pix, K, None, iterationsCount=1000, reprojectionError=3.0,
                                          confidence=0.9999, flags=cv2.SOLVEPNP_EPNP)
    assert np.array_equal(res.ransac_inliers, np.sort(inl.reshape(-1)))
    assert not np.array_equal(res.ransac_inliers, res.inliers)  # here the refined pose re-scores others
    assert np.count_nonzero(res.ransac_inliers < n_out) <= 2  # the gross outliers stay out
    assert np.array_equal(inverse_result(res).ransac_inliers, res.ransac_inliers)


def test_a_fit_is_reused_where_only_the_gates_differ() -> None:
    """`fits`: a problem solved again with another inlier floor reuses the fit (RANSAC does not see
    the gates) and gives what a fresh solve gives; other points are a new problem."""
    pts, pix, _, _ = scene(n=60, outlier_frac=0.5)
    fits: dict = {}  # type: ignore[type-arg]
    strict, loose = PnpParams(min_inliers=40, min_inlier_ratio=0.0), PnpParams(min_inliers=20, min_inlier_ratio=0.0)
    a = solve_pnp(pts, pix, K, strict, fits)
    b = solve_pnp(pts, pix, K, loose, fits)
    assert len(fits) == 1
    assert (a.accepted, a.refusal, b.accepted, b.refusal) == (False, Refusal.INLIERS, True, Refusal.NONE)
    fresh = solve_pnp(pts, pix, K, loose)
    assert np.array_equal(b.T_target_source, fresh.T_target_source) and np.array_equal(b.inliers, fresh.inliers)
    solve_pnp(pts[1:], pix[1:], K, loose, fits)
    assert len(fits) == 2
