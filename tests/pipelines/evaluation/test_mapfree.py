"""The map-free metrics against values worked out by hand from the benchmark's definitions."""

from __future__ import annotations

import numpy as np
import pytest

from litevloc.base.geometry import make_T, so3_exp
from litevloc.pipelines.evaluation.mapfree import (
    QueryScore,
    mapfree_metrics,
    pose_errors,
    precision_recall_auc,
    vcre_px,
    virtual_points,
)

K = np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]])


def test_virtual_grid_is_the_published_one() -> None:
    g = virtual_points()
    assert g.shape == (196, 3)
    assert np.allclose(sorted(set(np.round(g[:, 0], 6))), np.arange(-0.9, 0.91, 0.3))
    assert np.allclose(sorted(set(np.round(g[:, 1], 6))), [-0.45, -0.15, 0.15, 0.45])
    assert np.allclose(sorted(set(np.round(g[:, 2], 6))), 1.8 + 0.3 * np.arange(7))


def test_vcre_of_a_sideways_shift_is_f_times_shift_over_depth() -> None:
    T_gt = make_T(so3_exp(np.array([0.1, -0.2, 0.05])), np.array([0.3, -0.1, 2.0]))
    assert vcre_px(T_gt, T_gt, K, 640, 480) == pytest.approx(0.0, abs=1e-9)
    # the estimate's camera is 1 cm to the left: every virtual point moves f * 0.01 / z pixels
    T_est = make_T(np.eye(3), np.array([0.01, 0.0, 0.0])) @ T_gt
    z = virtual_points()[:, 2]
    assert vcre_px(T_est, T_gt, K, 640, 480) == pytest.approx(float(np.mean(500 * 0.01 / z)), rel=1e-9)
    # projections are clamped to the image: a huge error saturates instead of growing
    far = make_T(np.eye(3), np.array([50.0, 0.0, 0.0])) @ T_gt
    assert vcre_px(far, T_gt, K, 640, 480) <= 640.0


def test_pose_errors_are_centre_distance_and_angle() -> None:
    T_gt = make_T(so3_exp(np.array([0.0, 0.3, 0.0])), np.array([1.0, 0.0, 0.5]))  # world -> camera
    T_est = make_T(so3_exp(np.array([0.0, 0.0, np.radians(7.0)])), np.zeros(3)) @ T_gt
    dt, dr = pose_errors(T_est, T_gt)
    assert dt == pytest.approx(0.0, abs=1e-9) and dr == pytest.approx(7.0, rel=1e-9)  # rotation about the centre
    c_gt = -T_gt[:3, :3].T @ T_gt[:3, 3]
    T_shift = T_gt.copy()
    T_shift[:3, 3] = -T_gt[:3, :3] @ (c_gt + np.array([0.0, 0.2, 0.0]))
    assert pose_errors(T_shift, T_gt) == pytest.approx((0.2, 0.0), abs=1e-9)


def test_auc_worked_by_hand() -> None:
    # confidences 3, 2, 1 with hits T, F, T and one failure: precision 1, 1/2, 2/3 at recall 1/4, 2/4, 3/4
    auc = precision_recall_auc(np.array([3.0, 2.0, 1.0]), np.array([True, False, True]), failures=1)
    assert auc == pytest.approx(0.25 * (1.0 + 0.5 + 2 / 3))
    assert precision_recall_auc(np.array([1.0, 1.0]), np.array([True, True]), 0) == pytest.approx(1.0)
    assert precision_recall_auc(np.array([]), np.array([], bool), 3) == 0.0


def test_aggregate_counts_failures_and_averages_scene_medians() -> None:
    a = [QueryScore(0.1, 2.0, 10.0, 50.0), QueryScore(0.3, 1.0, 100.0, 40.0), QueryScore(0.2, 9.0, 20.0, 30.0)]
    b = [QueryScore(0.05, 1.0, 5.0, 99.0)]
    m = mapfree_metrics({"s1": a, "s2": b}, failures=1)
    assert m["Average Median Translation Error"] == pytest.approx((0.2 + 0.05) / 2)
    assert m["Average Median Rotation Error"] == pytest.approx((2.0 + 1.0) / 2)
    assert m["Average Median Reprojection Error"] == pytest.approx((20.0 + 5.0) / 2)
    assert m["Precision @ Pose Error < (25.0cm, 5deg)"] == pytest.approx(2 / 5)  # 0.1/2 and 0.05/1
    assert m["Precision @ VCRE < 90px"] == pytest.approx(3 / 5)
    assert m["Estimates for % of frames"] == pytest.approx(4 / 5)
    with pytest.raises(ValueError):
        mapfree_metrics({"s": []}, failures=2)
