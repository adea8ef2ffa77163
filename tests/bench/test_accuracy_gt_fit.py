"""bench/accuracy.py's check of the ground truth against the images (`gt_reprojection_px`)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from litevloc.base import geometry as g
from litevloc.base.params.localization import LocalizationParams
from litevloc.pipelines.localization.results import MatchedPixels
from tests.bench import load_bench


def test_ground_truth_that_fits_reprojects_to_zero_and_a_shifted_one_does_not() -> None:
    acc = load_bench("accuracy")
    K = np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]])
    depth = np.full((480, 640), 2.0, np.float32)  # a wall 2 m in front of the live camera
    rng = np.random.default_rng(0)
    live_px = rng.uniform([50, 50], [590, 430], size=(40, 2))
    pts = g.backproject_pixels(K, live_px, np.full(40, 2.0))
    T_map_kf = np.eye(4)
    T_gt = g.make_T(g.so3_exp(np.array([0.0, 0.1, 0.0])), [0.2, 0.0, 0.0])  # live camera in the map
    kf_px = g.project(K, g.transform_points(np.linalg.inv(T_map_kf) @ T_gt, pts))
    inlier = np.ones(40, bool)
    inlier[:5] = False  # not the estimate's inliers: left out
    kf_px[:5] += 50.0
    m = MatchedPixels(0, live_px.astype(np.float32), kf_px.astype(np.float32), inlier)
    topomap = SimpleNamespace(T_map_camera=np.stack([T_map_kf]), K=np.stack([K]))
    dp = LocalizationParams().depth
    assert acc.gt_reprojection_px(m, depth, K, T_gt, topomap, dp) < 0.1  # float32 pixels
    shifted = T_gt @ g.make_T(np.eye(3), [0.02, 0.0, 0.0])  # ground truth 2 cm off, sideways
    assert 4.0 < acc.gt_reprojection_px(m, depth, K, shifted, topomap, dp) < 6.0  # ~500 px x 2 cm / 2 m
    assert np.isnan(acc.gt_reprojection_px(m, None, K, T_gt, topomap, dp))
    none = MatchedPixels(0, m.live_px, m.keyframe_px, np.zeros(40, bool))
    assert np.isnan(acc.gt_reprojection_px(none, depth, K, T_gt, topomap, dp))
