from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from litevloc.base import geometry as g

finite = st.floats(-10, 10, allow_nan=False, allow_infinity=False)
quats = arrays(np.float64, 4, elements=st.floats(-1, 1, allow_nan=False)).filter(lambda q: np.linalg.norm(q) > 0.1)
vec3 = arrays(np.float64, 3, elements=finite)


def random_T(q: np.ndarray, t: np.ndarray) -> np.ndarray:
    return g.make_T(g.quat_xyzw_to_matrix(q), t)


@settings(max_examples=200, deadline=None)
@given(quats)
def test_quaternion_round_trip(q: np.ndarray) -> None:
    R = g.quat_xyzw_to_matrix(q)
    assert np.allclose(R @ R.T, np.eye(3), atol=1e-12) and np.isclose(np.linalg.det(R), 1)
    q2 = g.matrix_to_quat_xyzw(R)
    qn = q / np.linalg.norm(q)
    assert np.allclose(q2, qn, atol=1e-9) or np.allclose(q2, -qn, atol=1e-9)
    assert np.allclose(g.quat_xyzw_to_matrix(q2), R, atol=1e-12)


def test_quaternion_order_is_xyzw() -> None:
    # 90 deg about z: q = (0, 0, sin45, cos45)
    R = g.quat_xyzw_to_matrix(np.array([0, 0, np.sin(np.pi / 4), np.cos(np.pi / 4)]))
    assert np.allclose(R @ [1, 0, 0], [0, 1, 0])
    with pytest.raises(g.GeometryError):
        g.quat_xyzw_to_matrix(np.zeros(4))


@settings(max_examples=100, deadline=None)
@given(quats, vec3, quats, vec3)
def test_compose_invert(q1: np.ndarray, t1: np.ndarray, q2: np.ndarray, t2: np.ndarray) -> None:
    A, B = random_T(q1, t1), random_T(q2, t2)
    assert np.allclose(g.compose(A, g.invert(A)), np.eye(4), atol=1e-9)
    assert np.allclose(g.invert(g.compose(A, B)), g.compose(g.invert(B), g.invert(A)), atol=1e-9)
    p = np.array([[0.3, -1.0, 2.0]])
    assert np.allclose(g.transform_points(g.compose(A, B), p), g.transform_points(A, g.transform_points(B, p)))
    assert g.is_rigid(A)


@settings(max_examples=100, deadline=None)
@given(arrays(np.float64, 3, elements=st.floats(-3, 3, allow_nan=False)))
def test_so3_exp_log(w: np.ndarray) -> None:
    if np.linalg.norm(w) >= np.pi - 1e-6:
        return
    assert np.allclose(g.so3_log(g.so3_exp(w)), w, atol=1e-8)


def test_interpolation_by_timestamp() -> None:
    T0 = np.eye(4)
    T1 = g.make_T(g.so3_exp(np.array([0, 0, np.pi / 2])), [2.0, 0, 0])
    times = np.array([100, 300], dtype=np.int64)
    poses = np.stack([T0, T1])
    mid = g.interpolate_pose_at(200, times, poses)
    assert np.allclose(mid[:3, 3], [1, 0, 0])
    assert np.isclose(np.degrees(g.rotation_angle(mid[:3, :3])), 45)
    assert np.allclose(g.interpolate_pose_at(100, times, poses), T0)
    assert np.allclose(g.interpolate_pose_at(300, times, poses), T1)
    with pytest.raises(g.GeometryError, match="outside"):
        g.interpolate_pose_at(301, times, poses)


def test_check_rigid_rejects_bad() -> None:
    T = np.eye(4)
    T[0, 0] = 2
    with pytest.raises(g.GeometryError):
        g.check_rigid(T, "T_map_camera")
    T = np.eye(4)
    T[1, 3] = np.nan
    assert not g.is_rigid(T)


def test_backproject_project_round_trip() -> None:
    intr = g.PinholeIntrinsics(585, 585, 320, 240, 640, 480)
    rng = np.random.default_rng(0)
    depth = rng.uniform(0.5, 4, (480, 640)).astype(np.float32)
    depth[10:20, 10:20] = np.nan
    depth[30, 30] = 0
    pts, uv = g.backproject_depth(depth, intr.K, stride=4)
    assert len(pts) == len(uv) and np.all(np.isfinite(pts))
    assert np.allclose(g.project(intr.K, pts), uv, atol=1e-9)
    assert np.allclose(pts[:, 2], depth[uv[:, 1], uv[:, 0]], atol=1e-6)
    with pytest.raises(g.GeometryError):
        g.backproject_depth(depth[None], intr.K)


def test_intrinsics_scaling() -> None:
    intr = g.PinholeIntrinsics(585, 585, 319.5, 239.5, 640, 480)
    half = intr.scaled(320, 240)
    assert np.isclose(half.fx, 292.5) and np.isclose(half.cx, 159.5) and np.isclose(half.cy, 119.5)
    assert np.allclose(g.PinholeIntrinsics.from_K(intr.K, 640, 480).K, intr.K)
    with pytest.raises(g.GeometryError):
        g.PinholeIntrinsics(-1, 1, 0, 0, 10, 10)
