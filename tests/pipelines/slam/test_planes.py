"""Walls as plane landmarks (`slam.planes`): planes found in depth points, associated across
keyframes, and a corridor whose visual edges each turn a little straightened by its walls."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from litevloc.base.geometry import invert, make_T, so3_exp
from litevloc.base.params.slam import SlamGraphParams, SlamPlaneParams
from litevloc.pipelines.slam.graph import optimise
from litevloc.pipelines.slam.planes import PlaneObservation, associate, optimise_with_walls, wall_planes
from litevloc.pipelines.slam.types import Edge

# a forward camera (z ahead, y down) level in a corridor along map x, map z up
R_MAP_CAMERA = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
UP = np.array([0.0, 0.0, 1.0])


def _corridor_points(T_map_camera: np.ndarray, rng: np.random.Generator, n: int = 600) -> np.ndarray:
    """Depth-like points (camera frame) of a corridor along map x: walls at y = +-1 m (0-2.5 m
    high), the floor at z = 0 with the camera 1 m above it, 1 cm noise."""
    x = T_map_camera[0, 3] + rng.uniform(0.5, 5.0, 3 * n)
    left = np.stack([x[:n], np.full(n, 1.0), rng.uniform(0, 2.5, n)], 1)
    right = np.stack([x[n:2 * n], np.full(n, -1.0), rng.uniform(0, 2.5, n)], 1)
    floor = np.stack([x[2 * n:], rng.uniform(-1, 1, n), np.zeros(n)], 1)
    pts = np.concatenate([left, right, floor]) + rng.normal(0, 0.01, (3 * n, 3))
    T_cm = invert(T_map_camera)
    return pts @ T_cm[:3, :3].T + T_cm[:3, 3]


def _camera_at(x: float, yaw_rad: float = 0.0, y: float = 0.0) -> np.ndarray:
    return make_T(so3_exp(np.array([0.0, 0.0, yaw_rad])) @ R_MAP_CAMERA, np.array([x, y, 1.0]))


def test_walls_are_found_and_the_floor_is_not() -> None:
    T = _camera_at(0.0)
    planes = wall_planes(_corridor_points(T, np.random.default_rng(0)), R_MAP_CAMERA.T @ UP, SlamPlaneParams())
    assert len(planes) == 2
    for p in planes:
        n_map = R_MAP_CAMERA @ p.n
        assert abs(abs(n_map[1]) - 1.0) < 1e-3  # normal along map y: a wall, not the floor
        assert abs(p.d - 1.0) < 0.01  # each wall 1 m from the camera, normal toward it
        assert p.lo < 0 < p.hi and p.hi - p.lo > 3.0


def _obs(n_cam: np.ndarray, d: float, centre: np.ndarray) -> PlaneObservation:
    return PlaneObservation(n_cam, d, centre, -1.0, 1.0, 1.0, 100)


def test_association_joins_one_wall_and_keeps_others_apart() -> None:
    params = SlamPlaneParams(min_keyframes=1)
    n_left = R_MAP_CAMERA.T @ np.array([0.0, -1.0, 0.0])  # the wall at map y = +1 seen from y = 0
    poses = {0: _camera_at(0.0), 1: _camera_at(1.5), 2: _camera_at(1.5, y=0.9), 3: _camera_at(9.0)}
    obs = {
        0: [_obs(n_left, 1.0, np.array([-1.0, 0.0, 2.0]))],
        1: [_obs(n_left, 1.0, np.array([-1.0, 0.0, 2.0]))],  # the same wall 1.5 m on
        2: [_obs(n_left, 0.1, np.array([-0.1, 0.0, 2.0]))],  # the same wall seen from 0.1 m (the camera at y 0.9)
        3: [_obs(n_left, 1.0, np.array([-1.0, 0.0, 2.0]))],  # in line with it, 6 m past its end
    }
    walls = associate(obs, poses, UP, params)
    members = sorted(sorted(k for k, _ in w.members) for w in walls)
    assert members == [[0, 1, 2], [3]]
    # a parallel plane 0.5 m off the wall is another wall
    obs[2] = [_obs(n_left, 0.5, np.array([-0.5, 0.0, 2.0]))]
    poses[2] = _camera_at(1.5)
    members = sorted(sorted(k for k, _ in w.members) for w in associate(obs, poses, UP, params))
    assert members == [[0, 1], [2], [3]]


def test_walls_straighten_a_corridor_that_visual_edges_bend() -> None:
    n = 40
    truth = [_camera_at(0.3 * i) for i in range(n)]
    turn = make_T(so3_exp(np.array([0.0, np.radians(0.03), 0.0])), np.zeros(3))  # about camera y: a yaw
    cov = np.diag([np.radians(0.3) ** 2] * 3 + [0.003**2] * 3)
    edges, T_init = [], [truth[0]]
    for i in range(n - 1):
        edges.append(Edge(i, i + 1, invert(truth[i]) @ truth[i + 1] @ turn, cov, "visual"))
        T_init.append(T_init[-1] @ edges[-1].T_a_b)
    kfs = [SimpleNamespace(id=i, chain=0, T_init=T) for i, T in enumerate(T_init)]
    gp = SlamGraphParams(visual_covariance_scale=1.0)
    chain = optimise(kfs, edges, truth[0], gp)
    rng = np.random.default_rng(0)
    clouds = {i: _corridor_points(truth[i], rng, 300) for i in range(n)}
    walled, res = optimise_with_walls(kfs, clouds, edges, chain, truth[0], UP, gp, SlamPlaneParams())
    off_chain = max(abs(chain.poses[i][1, 3]) for i in range(n))
    off_walls = max(abs(walled.poses[i][1, 3]) for i in range(n))
    assert off_chain > 0.05  # the chain bends ~10 cm sideways over 12 m
    assert res.walls == 2 and res.factors.count >= 2 * n - 2
    assert off_walls < 0.02
