"""Keypoint alignment on an exactly rendered floor (tests/pipelines/floor_views.py)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from litevloc.base.geometry import backproject_pixels, transform_points
from litevloc.base.params.slam import KeypointAlignmentParams
from litevloc.pipelines.depth_lookup import depth_at
from litevloc.pipelines.keypoint_alignment import (
    align_keypoints,
    alignment_view,
    plane_homographies,
    surface_normals,
)
from tests.pipelines import floor_views
from tests.pipelines.floor_views import K


@pytest.fixture(scope="module")
def floor_pair() -> dict[str, np.ndarray]:
    return floor_views.floor_pair()


def test_normals_of_a_plane_and_nan_at_a_depth_edge() -> None:
    T = floor_views.looking_along_x(0.0)
    _, depth = floor_views.floor_camera(T, floor_views.texture())
    uv = np.array([[320.0, 400.0], [100.0, 300.0]])
    n = surface_normals(depth, K, uv, 4, 0.01)
    up_in_camera = T[:3, :3].T @ np.array([0, 0, 1.0])
    assert np.allclose(n, up_in_camera[None], atol=2e-3)
    step = depth.copy()
    step[:, 322:] *= 0.5  # an object's edge beside the first pixel
    n2 = surface_normals(step, K, uv, 4, 0.01)
    assert np.all(np.isnan(n2[0])) and np.allclose(n2[1], up_in_camera, atol=2e-3)


def test_plane_homography_maps_plane_points() -> None:
    rng = np.random.default_rng(1)
    n = np.array([0.0, -0.8, -0.6])
    P = rng.uniform(-1, 1, (5, 3)) + np.array([0.0, 0.0, 4.0])
    P -= np.outer(P @ n - (-2.0), n)  # onto the plane n . X = -2
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(np.array([0.02, -0.05, 0.01]))[0]
    T[:3, 3] = [0.1, -0.05, -0.3]
    Hs = plane_homographies(K, K, T, P, np.tile(n, (5, 1)))
    for i in range(5):
        Q = rng.uniform(-0.5, 0.5, 3)
        Q -= (Q @ n + 2.0) * n  # another point of the same plane
        q = K @ Q
        h = Hs[i] @ q
        X = transform_points(T, Q[None])[0]
        assert np.allclose(h[:2] / h[2], (K @ X)[:2] / X[2], atol=1e-9)


def test_aligned_keypoints_land_on_the_source_surface_point(floor_pair: dict[str, np.ndarray]) -> None:
    """On a floor seen at a grazing angle, matched keypoints 1 px off (as a detector's are) are
    moved onto the true image of the source's point; plain translation-only LK (no plane warp) is
    biased there, which is why the warp matters."""
    src = alignment_view(floor_pair["cs"], floor_pair["ds"], K)
    tgt = alignment_view(floor_pair["ct"], floor_pair["dt"], K)
    uv_s = floor_views.keypoints(floor_pair["ds"], 150, 0)
    z = depth_at(floor_pair["ds"], uv_s).astype(np.float64)  # lifted as the front end lifts them
    P = backproject_pixels(K, uv_s, z)
    X = transform_points(floor_pair["T_t_s"], P)
    truth = (K @ X.T).T
    truth = truth[:, :2] / truth[:, 2:3]
    rng = np.random.default_rng(2)
    start = truth + rng.uniform(-1.0, 1.0, truth.shape)
    params = KeypointAlignmentParams()
    out, done = align_keypoints(src, tgt, uv_s, P, start, floor_pair["T_t_s"], params)
    assert done.mean() > 0.8
    err = np.linalg.norm(out[done] - truth[done], axis=1)
    assert np.median(err) < 0.08 and np.percentile(err, 90) < 0.3
    assert abs(np.mean(out[done, 1] - truth[done, 1])) < 0.02  # no bias along the floor's foreshortening
    assert np.array_equal(out[~done], start[~done])  # failures come back unmoved
    # the same alignment with the surface taken as facing the camera (no foreshortening) misses
    flat = alignment_view(floor_pair["cs"], np.full_like(floor_pair["ds"], 2.0), K)
    out_flat, done_flat = align_keypoints(flat, tgt, uv_s, P, start, floor_pair["T_t_s"], params)
    both = done & done_flat
    assert np.median(np.linalg.norm(out_flat[both] - truth[both], axis=1)) > 3 * np.median(err)


def test_textureless_patches_are_left_alone(floor_pair: dict[str, np.ndarray]) -> None:
    blank = np.full_like(floor_pair["ct"], 128)
    src = alignment_view(blank, floor_pair["ds"], K)
    tgt = alignment_view(blank, floor_pair["dt"], K)
    uv_s = floor_views.keypoints(floor_pair["ds"], 20, 3)
    z = floor_pair["ds"][np.rint(uv_s[:, 1]).astype(int), np.rint(uv_s[:, 0]).astype(int)].astype(np.float64)
    P = backproject_pixels(K, uv_s, z)
    start = uv_s + 1.0
    out, done = align_keypoints(src, tgt, uv_s, P, start, floor_pair["T_t_s"], KeypointAlignmentParams())
    assert not done.any() and np.array_equal(out, start)
