"""Metric depth from a rectified stereo pair, for cameras without an on-board depth engine.

rectified left/right -> disparity (OpenCV semi-global block matching, `cv2.StereoSGBM`)
-> optional left-right consistency check -> depth `Z = f * B / (d + doffs)`.

Conventions: images HxW (grey) or HxWx3 (RGB) uint8, rectified so that a scene point at
column `x` in the left image is at `x - d` in the right image (`d >= 0`). Disparity and
depth are HxW float32 on the LEFT image grid with NaN = invalid. `focal_px` is the
rectified focal length in pixels, `baseline_m` the distance between the optical centres
in metres, `doffs_px` the principal-point difference `cx_right - cx_left` (0 for pairs
rectified with a common principal point, as `cv2.stereoRectify` makes by default).

The left-right check replaces OpenCV-contrib's WLS/`createRightMatcher` (not in
opencv-python-headless): the right disparity is SGBM run on the mirrored pair.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from litevloc.base.params.depth import SgbmParams

_MODES = {
    "sgbm": cv2.STEREO_SGBM_MODE_SGBM,
    "hh": cv2.STEREO_SGBM_MODE_HH,
    "sgbm_3way": cv2.STEREO_SGBM_MODE_SGBM_3WAY,
    "hh4": cv2.STEREO_SGBM_MODE_HH4,
}


def _matcher(params: SgbmParams, channels: int) -> cv2.StereoSGBM:
    area = channels * params.block_size**2
    sgbm: cv2.StereoSGBM = cv2.StereoSGBM_create(  # type: ignore[attr-defined]
        minDisparity=params.min_disparity,
        numDisparities=params.num_disparities,
        blockSize=params.block_size,
        P1=params.p1 * area,
        P2=params.p2 * area,
        disp12MaxDiff=params.disp12_max_diff,
        uniquenessRatio=params.uniqueness_ratio,
        speckleWindowSize=params.speckle_window_size,
        speckleRange=params.speckle_range,
        preFilterCap=params.pre_filter_cap,
        mode=_MODES[params.mode],
    )
    return sgbm


def _check_pair(left: NDArray[np.uint8], right: NDArray[np.uint8]) -> None:
    if left.shape != right.shape:
        raise ValueError(f"left {left.shape} and right {right.shape} images must have the same shape")
    if left.dtype != np.uint8 or right.dtype != np.uint8:
        raise ValueError(f"stereo images must be uint8, got {left.dtype} and {right.dtype}")
    if left.ndim not in (2, 3) or (left.ndim == 3 and left.shape[2] not in (1, 3)):
        raise ValueError(f"stereo images must be HxW or HxWx3, got {left.shape}")


def _raw_disparity(matcher: cv2.StereoSGBM, left: NDArray[np.uint8], right: NDArray[np.uint8],
                   min_disparity: int, num_disparities: int) -> NDArray[np.float32]:
    # OpenCV leaves the first min+num disparity columns unmatched; pad them on the left so
    # pixels whose match is inside the image get a disparity there too, then crop.
    pad = max(0, min_disparity + num_disparities)
    lp = cv2.copyMakeBorder(left, 0, 0, pad, 0, cv2.BORDER_CONSTANT, value=0)
    rp = cv2.copyMakeBorder(right, 0, 0, pad, 0, cv2.BORDER_CONSTANT, value=0)
    raw = matcher.compute(lp, rp)[:, pad:]  # int16, disparity * 16; invalid = (minDisparity - 1) * 16
    d = raw.astype(np.float32) / np.float32(16.0)
    d[raw < min_disparity * 16] = np.nan
    return d


def compute_disparity(left: NDArray[np.uint8], right: NDArray[np.uint8],
                      params: SgbmParams = SgbmParams()) -> NDArray[np.float32]:
    """Rectified pair -> left-image disparity, HxW float32 pixels, NaN = invalid.

    With `params.lr_max_diff_px >= 0`, pixels whose disparity disagrees with the
    right-image disparity at the matched column by more than that are set NaN
    (occlusions, mismatches). Releases the GIL inside OpenCV.
    """
    _check_pair(left, right)
    channels = 1 if left.ndim == 2 else left.shape[2]
    matcher = _matcher(params, channels)
    d_left = _raw_disparity(matcher, left, right, params.min_disparity, params.num_disparities)
    if params.lr_max_diff_px < 0:
        return d_left
    # Right-image disparity: match the mirrored pair (right becomes the reference image).
    d_right = _raw_disparity(matcher, np.ascontiguousarray(right[:, ::-1]), np.ascontiguousarray(left[:, ::-1]),
                             params.min_disparity, params.num_disparities)[:, ::-1]
    h, w = d_left.shape
    xs = np.arange(w, dtype=np.float32)[None, :]
    xr = np.rint(xs - np.nan_to_num(d_left, nan=-1e6)).astype(np.int64)  # NaN -> out of range
    inside = (xr >= 0) & (xr < w)
    rows = np.broadcast_to(np.arange(h)[:, None], (h, w))
    d_r_at = np.full((h, w), np.nan, dtype=np.float32)
    d_r_at[inside] = d_right[rows[inside], xr[inside]]
    with np.errstate(invalid="ignore"):
        consistent = np.abs(d_left - d_r_at) <= params.lr_max_diff_px
    return np.where(consistent, d_left, np.float32(np.nan)).astype(np.float32)


def disparity_to_depth(disparity: NDArray[np.floating], focal_px: float, baseline_m: float,
                       doffs_px: float = 0.0) -> NDArray[np.float32]:
    """Disparity (px, NaN invalid) -> depth `f*B/(d+doffs)` HxW float32 metres, NaN invalid.

    Non-finite disparities and those with `d + doffs <= 0` (at or beyond infinity) are NaN.
    """
    if not (focal_px > 0 and baseline_m > 0 and np.isfinite(focal_px) and np.isfinite(baseline_m)):
        raise ValueError(f"focal_px and baseline_m must be positive, got {focal_px}, {baseline_m}")
    d = np.asarray(disparity, dtype=np.float64) + float(doffs_px)
    valid = np.isfinite(d) & (d > 0)
    out = np.full(d.shape, np.nan, dtype=np.float32)
    out[valid] = (float(focal_px) * float(baseline_m) / d[valid]).astype(np.float32)
    return out


def stereo_depth(left: NDArray[np.uint8], right: NDArray[np.uint8], focal_px: float, baseline_m: float,
                 params: SgbmParams = SgbmParams(), doffs_px: float = 0.0) -> NDArray[np.float32]:
    """Rectified pair -> HxW float32 depth in metres on the left image grid, NaN = invalid."""
    return disparity_to_depth(compute_disparity(left, right, params), focal_px, baseline_m, doffs_px)


@dataclass(frozen=True)
class DisparityScores:
    """Accuracy against ground truth, over pixels with valid ground truth.

    `bad_1px`/`bad_3px`: fraction of those pixels whose estimate is missing or off by more
    than 1/3 px (missing counts as bad, the Middlebury "all pixels, no fill" convention).
    `bad_*_est`: the same over pixels that have an estimate. `density`: fraction with an
    estimate. `median_abs_err_px` and depth errors are over pixels that have an estimate.
    """

    bad_1px: float
    bad_3px: float
    bad_1px_est: float
    bad_3px_est: float
    density: float
    median_abs_err_px: float
    median_depth_err_m: float
    median_rel_depth_err: float
    n_gt: int


def score_disparity(disparity: NDArray[np.floating], gt: NDArray[np.floating], focal_px: float,
                    baseline_m: float, doffs_px: float = 0.0) -> DisparityScores:
    """Compare an estimated disparity with ground truth (both HxW, non-finite = invalid)."""
    if disparity.shape != gt.shape:
        raise ValueError(f"disparity {disparity.shape} and ground truth {gt.shape} differ in shape")
    g = np.asarray(gt, dtype=np.float64)
    e = np.asarray(disparity, dtype=np.float64)
    has_gt = np.isfinite(g)
    n = int(has_gt.sum())
    if n == 0:
        raise ValueError("ground truth has no valid pixel")
    est = has_gt & np.isfinite(e)
    err = np.abs(e[est] - g[est])
    n_est = max(int(est.sum()), 1)
    z_gt = disparity_to_depth(g[est], focal_px, baseline_m, doffs_px).astype(np.float64)
    z_est = disparity_to_depth(e[est], focal_px, baseline_m, doffs_px).astype(np.float64)
    ok = np.isfinite(z_gt) & np.isfinite(z_est)
    dz = np.abs(z_est[ok] - z_gt[ok])
    return DisparityScores(
        bad_1px=float((n - (err <= 1.0).sum()) / n),
        bad_3px=float((n - (err <= 3.0).sum()) / n),
        bad_1px_est=float((err > 1.0).sum() / n_est),
        bad_3px_est=float((err > 3.0).sum() / n_est),
        density=float(est.sum() / n),
        median_abs_err_px=float(np.median(err)) if err.size else float("nan"),
        median_depth_err_m=float(np.median(dz)) if dz.size else float("nan"),
        median_rel_depth_err=float(np.median(dz / z_gt[ok])) if dz.size else float("nan"),
        n_gt=n,
    )
