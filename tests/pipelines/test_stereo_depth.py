"""Stereo depth (SGBM): synthetic exactness and Middlebury motorcycle accuracy."""

from __future__ import annotations

import numpy as np
import pytest

from litevloc.pipelines.stereo_depth import (
    SgbmParams,
    compute_disparity,
    disparity_to_depth,
    score_disparity,
    stereo_depth,
)

# Calibration of scikit-image's 4x down-sampled Middlebury 2014 "Motorcycle" pair (its docstring).
MOTO_F_PX = 994.978
MOTO_B_M = 0.193001
MOTO_DOFFS_PX = 31.086


@pytest.fixture(scope="module")
def motorcycle() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    data = pytest.importorskip("skimage.data")
    left, right, gt = data.stereo_motorcycle()
    return left, right, gt


@pytest.fixture(scope="module")
def moto_scores(motorcycle: tuple[np.ndarray, np.ndarray, np.ndarray]) -> dict[str, object]:
    left, right, gt = motorcycle
    return {
        "lr": score_disparity(compute_disparity(left, right), gt, MOTO_F_PX, MOTO_B_M, MOTO_DOFFS_PX),
        "raw": score_disparity(compute_disparity(left, right, SgbmParams(lr_max_diff_px=-1)), gt,
                               MOTO_F_PX, MOTO_B_M, MOTO_DOFFS_PX),
    }


def test_params_validation() -> None:
    for bad in ({"num_disparities": 40}, {"block_size": 4}, {"p1": 40, "p2": 32}, {"mode": "bm"},
                {"pre_filter_cap": 0}):
        with pytest.raises(ValueError):
            SgbmParams(**bad)


def test_disparity_to_depth_formula_and_invalid() -> None:
    d = np.array([[10.0, 0.0, np.nan, -5.0, 2.0]], dtype=np.float32)
    z = disparity_to_depth(d, focal_px=500.0, baseline_m=0.1)
    assert z.dtype == np.float32
    np.testing.assert_allclose(z[0, [0, 4]], [5.0, 25.0])
    assert np.isnan(z[0, 1:4]).all()
    np.testing.assert_allclose(disparity_to_depth(d, 500.0, 0.1, doffs_px=10.0)[0, 0], 2.5)
    with pytest.raises(ValueError):
        disparity_to_depth(d, 0.0, 0.1)


def test_synthetic_fronto_parallel_plane() -> None:
    # A random texture shifted by 12 px: every matched pixel must find d = 12, depth f*B/12.
    rng = np.random.default_rng(0)
    right = (rng.random((120, 200)) * 255).astype(np.uint8)
    right = np.repeat(np.repeat(right, 2, axis=0), 2, axis=1)[:120, :200].copy()
    left = np.zeros_like(right)
    left[:, 12:] = right[:, :-12]
    depth = stereo_depth(left, right, focal_px=400.0, baseline_m=0.075)
    inner = depth[10:-10, 80:-10]
    assert np.isfinite(inner).mean() > 0.95
    np.testing.assert_allclose(np.nanmedian(inner), 400.0 * 0.075 / 12.0, rtol=1e-3)
    assert np.isnan(depth[:, :12]).all()  # no match possible left of the shift


def test_shape_and_dtype_errors() -> None:
    a = np.zeros((10, 20), np.uint8)
    with pytest.raises(ValueError, match="same shape"):
        compute_disparity(a, np.zeros((10, 21), np.uint8))
    with pytest.raises(ValueError, match="uint8"):
        compute_disparity(a.astype(np.float32), a.astype(np.float32))  # type: ignore[arg-type]


def test_middlebury_motorcycle_accuracy(moto_scores: dict[str, object]) -> None:
    lr = moto_scores["lr"]
    raw = moto_scores["raw"]
    # Measured (opencv-python-headless 5.0, defaults): bad-3px 15.3 % of GT pixels (missing = bad), 4.4 % of
    # estimated pixels, density 0.886, median depth error 7.0 mm. Thresholds leave a margin
    # but catch a broken matcher or a lost border band.
    assert lr.bad_3px < 0.18  # type: ignore[attr-defined]
    assert lr.bad_3px_est < 0.055  # type: ignore[attr-defined]
    assert lr.bad_1px_est < 0.08  # type: ignore[attr-defined]
    assert lr.density > 0.86  # type: ignore[attr-defined]
    assert lr.median_depth_err_m < 0.01  # type: ignore[attr-defined]
    # the left-right check trades density for fewer wrong matches
    assert lr.bad_3px_est < raw.bad_3px_est and lr.density < raw.density  # type: ignore[attr-defined]


def test_middlebury_score_detects_a_miscalibrated_pair(motorcycle: tuple[np.ndarray, ...]) -> None:
    # Shifting the right image by 4 px (a rectification error) must show up as bad pixels.
    left, right, gt = motorcycle
    shifted = np.zeros_like(right)
    shifted[:, 4:] = right[:, :-4]
    s = score_disparity(compute_disparity(left, shifted), gt, MOTO_F_PX, MOTO_B_M, MOTO_DOFFS_PX)
    assert s.bad_3px_est > 0.5
