"""Projective point-to-plane alignment of map points onto a live depth image."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from litevloc.base import geometry as g
from litevloc.pipelines.localization.depth_align import align_to_live_depth

K = np.array([[300.0, 0, 160], [0, 300.0, 120], [0, 0, 1]])
H, W = 240, 320
# a room corner in the map frame: floor y = 0.6 (camera y points down), walls z = 2.5 and x = 1.0
PLANES = [(np.array([0.0, 1.0, 0.0]), 0.6), (np.array([0.0, 0.0, 1.0]), 2.5), (np.array([1.0, 0.0, 0.0]), 1.0)]


def corner_depth(T_map_cam: NDArray[np.float64]) -> NDArray[np.float64]:
    """Depth image (metres) of the corner seen from `T_map_cam`."""
    v, u = np.mgrid[0:H, 0:W]
    rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones((H, W))], -1).reshape(-1, 3)
    R, c = T_map_cam[:3, :3], T_map_cam[:3, 3]
    d_map = rays @ R.T
    best = np.full(len(rays), np.inf)
    for n, off in PLANES:
        denom = d_map @ n
        with np.errstate(divide="ignore", invalid="ignore"):
            s = (off - c @ n) / denom
        best = np.where((s > 0) & (s < best), s, best)
    return np.where(np.isfinite(best), best, 0.0).reshape(H, W)  # s along a z = 1 ray is the depth


def corner_points(T_map_cam: NDArray[np.float64], step: int = 6) -> NDArray[np.float64]:
    """Map points of the corner, lifted from a depth image rendered at `T_map_cam`."""
    P, _ = g.backproject_depth(corner_depth(T_map_cam), K, stride=step)
    return g.transform_points(T_map_cam, P)


def test_a_pose_ten_centimetres_off_is_moved_onto_the_live_surface() -> None:
    T_true = g.make_T(g.so3_exp(np.array([0.1, 0.35, 0.02])), np.array([0.1, 0.0, 0.2]))
    depth = corner_depth(T_true)
    # the keyframe saw the corner from elsewhere (0.3 m, 10 deg away)
    points = corner_points(g.make_T(g.so3_exp(np.array([0.05, 0.52, 0.0])), np.array([-0.3, -0.1, 0.0])))
    T_off = T_true @ g.make_T(g.so3_exp(np.array([0.02, 0.03, -0.02])), np.array([0.06, -0.05, 0.07]))
    assert g.relative_pose_error(T_off, T_true)[0] > 0.09
    a = align_to_live_depth(points, T_off, K, depth)
    assert a is not None
    err_m, err_deg = g.relative_pose_error(a.T_map_live, T_true)
    assert err_m < 0.01 and err_deg < 0.5
    assert a.rms_m < 0.005 and a.pairs > 500
    assert abs(a.shift_m - g.relative_pose_error(T_off, T_true)[0]) < 0.01


def test_along_a_single_plane_the_pose_stays_where_the_depth_cannot_tell() -> None:
    """A wall alone fixes its normal's translation and two tilts; the slide along it stays put."""
    wall = np.stack(np.meshgrid(np.linspace(-1, 1, 30), np.linspace(-0.8, 0.8, 30)), -1).reshape(-1, 2)
    points = np.concatenate([wall, np.full((len(wall), 1), 2.0)], 1)
    depth = np.full((H, W), 2.0)
    T_off = g.make_T(np.eye(3), np.array([0.08, 0.0, 0.1]))  # 8 cm along the wall, 10 cm towards it
    a = align_to_live_depth(points, T_off, K, depth)
    assert a is not None
    assert abs(a.T_map_live[2, 3]) < 0.005  # the distance to the wall is corrected
    assert abs(a.T_map_live[0, 3] - 0.08) < 0.005  # the slide is not invented


def test_nothing_to_align_on_gives_none() -> None:
    points = corner_points(np.eye(4))
    assert align_to_live_depth(points, np.eye(4), K, np.zeros((H, W))) is None  # no live depth
    far = g.make_T(np.eye(3), np.array([0.0, 0.0, -5.0]))  # the live surface 5 m beyond every point
    assert align_to_live_depth(points, far, K, corner_depth(np.eye(4))) is None
