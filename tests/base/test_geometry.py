"""base.geometry helpers not covered through the pipelines' tests."""

from __future__ import annotations

import numpy as np

from litevloc.base.geometry import make_T, pixels_in_view, undistort_normalized


def test_undistort_normalized_inverts_the_radial_model() -> None:
    x = np.random.default_rng(1).uniform(-0.6, 0.6, (50, 2))
    k1, k2 = -0.07, 0.02
    r2 = np.sum(x * x, axis=1, keepdims=True)
    xd = x * (1 + k1 * r2 + k2 * r2 * r2)
    np.testing.assert_allclose(undistort_normalized(xd, k1, k2), x, atol=1e-9)
    np.testing.assert_array_equal(undistort_normalized(xd, 0.0, 0.0), xd)  # no model: unchanged
    assert np.abs(xd - x).max() > 1e-3  # the model does move these points


def test_camera_position_covariance_matches_sampled_body_frame_perturbations() -> None:
    """Camera positions of `T_map_base @ exp(xi) @ T_base_camera`, xi ~ N(0, C) in ROS order
    (trans, rot; body frame), spread as the 3x3 covariance says: the lever arm carries the
    rotation's uncertainty to the camera."""
    from litevloc.base.geometry import camera_position_covariance, make_T, so3_exp

    rng = np.random.default_rng(3)
    T_map_base = make_T(so3_exp(np.array([0.1, -0.2, 1.2])), np.array([4.0, -2.0, 0.3]))
    T_base_camera = make_T(so3_exp(np.array([-1.2, 0.0, -1.5])), np.array([0.3, 0.05, 0.6]))
    C = np.diag([0.02, 0.01, 0.005, 0.002, 0.003, 0.04]) ** 2
    C[0, 5] = C[5, 0] = 0.5 * 0.02 * 0.04
    xi = rng.multivariate_normal(np.zeros(6), C, size=40000)
    pts = []
    for v in xi:
        dT = make_T(so3_exp(v[3:]), v[:3])  # first order as exp((v, w)) for small xi
        pts.append((T_map_base @ dT @ T_base_camera)[:3, 3])
    sampled = np.cov(np.asarray(pts).T)
    got = camera_position_covariance(T_map_base, C, T_base_camera)
    assert np.allclose(got, got.T)
    assert np.allclose(got, sampled, atol=0.04 * float(np.max(np.abs(sampled))))


def test_pixels_in_view_keeps_the_points_ahead_and_inside_the_image() -> None:
    K = np.array([[100.0, 0, 50], [0, 100.0, 40], [0, 0, 1]])
    world = np.array([[0.0, 0.0, 2.0], [0.0, 0.0, -2.0], [5.0, 0.0, 2.0], [0.1, 0.2, 1.0], [0.0, 0.0, -0.95]])
    T_cam_world = make_T(np.eye(3), [0.0, 0.0, 1.0])  # the world 1 m further ahead
    P, col, row = pixels_in_view(T_cam_world, world, K, (80, 100, 3))
    # behind the camera, outside the image and nearer than min_z are left out
    assert P.tolist() == [[0.0, 0.0, 3.0], [0.1, 0.2, 2.0]]
    assert col.tolist() == [50, 55] and row.tolist() == [40, 50]
