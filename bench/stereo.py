"""Stereo depth (SGBM) on the Middlebury 2014 Motorcycle pair shipped by scikit-image.

Accuracy over pixels with ground-truth disparity (bad-pixel rate at 1 and 3 px, missing
estimates counted as bad and, separately, over estimated pixels only; median depth
error) and time per pair (median of --repeats), at full resolution (741x500) and half
(370x250). Baseline = full-resolution grey SGBM without the left-right check, in the same
run. Calibration from scikit-image's docstring: f = 994.978 px, B = 193.001 mm,
doffs = 31.086 px (halved with the image for the half-resolution rows). Also times the
host JPEG round trip the OAK driver does per frame (`camera.jpeg_quality`).

    python bench/stereo.py [--repeats 5]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import cv2
import numpy as np
from _common import print_table, write_json

from litevloc.base.params.depth import SgbmParams
from litevloc.pipelines.stereo_depth import compute_disparity, score_disparity

F_PX, B_M, DOFFS_PX = 994.978, 0.193001, 31.086


def _gray(img: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)


def _half(img: np.ndarray) -> np.ndarray:
    return cv2.resize(img, (img.shape[1] // 2, img.shape[0] // 2), interpolation=cv2.INTER_AREA)


def _time(fn, repeats: int) -> float:  # type: ignore[no-untyped-def]
    fn()  # warm-up
    samples = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        samples.append(time.perf_counter() - t0)
    return float(np.median(samples))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    from skimage.data import stereo_motorcycle

    left, right, gt = stereo_motorcycle()
    h2, w2 = left.shape[0] // 2, left.shape[1] // 2
    gt_half = gt[: 2 * h2 : 2, : 2 * w2 : 2] / 2.0  # nearest sample, disparity halves with the width
    cases = [
        # name, left, right, gt, params, scale
        ("full grey, no LR check (baseline)", _gray(left), _gray(right), gt, SgbmParams(lr_max_diff_px=-1), 1.0),
        ("full grey, LR check (default)", _gray(left), _gray(right), gt, SgbmParams(), 1.0),
        ("full RGB, LR check", left, right, gt, SgbmParams(), 1.0),
        ("half grey, LR check, 32 disp", _gray(_half(left)), _gray(_half(right)), gt_half,
         SgbmParams(num_disparities=32, block_size=3), 0.5),
    ]
    rows, results = [], []
    base_s = None
    for name, lft, rgt, g, params, scale in cases:
        disp = compute_disparity(lft, rgt, params)
        s = score_disparity(disp, g, F_PX * scale, B_M, DOFFS_PX * scale)
        t = _time(lambda lft=lft, rgt=rgt, params=params: compute_disparity(lft, rgt, params), args.repeats)
        base_s = t if base_s is None else base_s
        rows.append([name, f"{lft.shape[1]}x{lft.shape[0]}", 100 * s.bad_1px, 100 * s.bad_3px,
                     100 * s.bad_3px_est, 100 * s.density, 1000 * s.median_depth_err_m, 1000 * t, base_s / t])
        results.append({"case": name, "width": lft.shape[1], "height": lft.shape[0], "params": repr(params),
                        **s.__dict__, "median_s": t, "speed_vs_baseline": base_s / t})
    print_table(
        f"SGBM on Middlebury Motorcycle (skimage), cv2 threads {cv2.getNumThreads()}, median of {args.repeats}",
        ["case", "size", "bad1 %", "bad3 %", "bad3 of est %", "density %", "med depth err mm", "ms",
         "speed vs baseline"],
        rows,
    )
    rgb = cv2.resize(left, (640, 480))

    def jpeg_round_trip() -> None:
        _ok, enc = cv2.imencode(".jpg", rgb[:, :, ::-1], [cv2.IMWRITE_JPEG_QUALITY, 95])
        cv2.imdecode(enc, cv2.IMREAD_COLOR)

    t_jpeg = _time(jpeg_round_trip, max(args.repeats, 20))
    print(f"host JPEG round trip (OAK camera.jpeg_quality=95), 640x480: {1000 * t_jpeg:.2f} ms median")
    write_json("stereo", {"calibration": {"focal_px": F_PX, "baseline_m": B_M, "doffs_px": DOFFS_PX},
                          "repeats": args.repeats, "cv2_threads": cv2.getNumThreads(), "cases": results,
                          "jpeg_round_trip_640x480_ms": 1000 * t_jpeg})


if __name__ == "__main__":
    main()
