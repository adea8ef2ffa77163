"""Planar-motion edges of a ground robot (`slam.planar`): a chain whose edges pitch the camera a
little too much climbs off the floor; the planar edges hold base_link's height and tilt, and
leave the motion in the plane to the other edges."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from litevloc.base.geometry import invert, make_T, so3_exp
from litevloc.base.params.slam import SlamGraphParams, SlamPlanarParams
from litevloc.pipelines.slam.graph import optimise
from litevloc.pipelines.slam.level import floor_of
from litevloc.pipelines.slam.planar import planar_edges
from litevloc.pipelines.slam.types import Edge
from tests.pipelines.slam.synthetic import T_BASE_CAMERA, lap_poses


def _biased_chain(n: int) -> tuple[list[SimpleNamespace], list[Edge], np.ndarray]:
    """Keyframes on half a lap (base z = 0) and visual-like edges each pitching the camera 0.3 deg
    too far, with a 1 deg rotation sigma; the keyframes' initial poses chain them."""
    T_base = lap_poses(n, 1.8, 0.5)
    cams = T_base @ T_BASE_CAMERA
    bias = make_T(so3_exp(np.array([np.radians(0.3), 0.0, 0.0])), np.zeros(3))
    cov = np.diag([np.radians(1.0) ** 2] * 3 + [0.002**2] * 3)
    T_cb = invert(T_BASE_CAMERA)
    edges, T_init = [], [np.eye(4)]
    for i in range(n - 1):
        M = invert(T_base[i]) @ T_base[i + 1]
        edges.append(Edge(i, i + 1, T_cb @ M @ T_BASE_CAMERA @ bias, cov, "visual"))
        T_init.append(T_init[-1] @ edges[-1].T_a_b)
    kfs = [SimpleNamespace(id=i, chain=0, T_init=T) for i, T in enumerate(T_init)]
    return kfs, edges, cams


def _bases(poses: dict[int, np.ndarray]) -> np.ndarray:
    return np.stack([poses[i] @ invert(T_BASE_CAMERA) for i in sorted(poses)])


def test_planar_edges_hold_the_base_on_the_floor() -> None:
    kfs, edges, cams = _biased_chain(40)
    graph = SlamGraphParams()
    free = optimise(kfs, edges, cams[0], graph)
    planar = planar_edges(kfs, T_BASE_CAMERA, SlamPlanarParams(enabled=True, sigma_height_m=0.001,
                                                               sigma_tilt_deg=0.02))
    assert len(planar) == len(kfs) - 1 and all(e.kind == "planar" for e in planar)
    held = optimise(kfs, edges + planar, cams[0], graph)
    z_free, z_held = np.abs(_bases(free.poses)[:, 2, 3]).max(), np.abs(_bases(held.poses)[:, 2, 3]).max()
    tilt_held = np.degrees(np.arccos(np.clip(_bases(held.poses)[:, 2, 2], -1, 1))).max()
    assert z_free > 0.1  # the bias really lifts the chain off the floor
    assert z_held < 0.01 and tilt_held < 0.2
    # x, y and yaw are left to the edges: the planar edges add no pull in the plane
    xy_free, xy_held = _bases(free.poses)[:, :2, 3], _bases(held.poses)[:, :2, 3]
    true_xy = (cams @ invert(T_BASE_CAMERA))[:, :2, 3]
    assert np.abs(xy_held - true_xy).max() <= np.abs(xy_free - true_xy).max() + 0.01


def test_planar_edges_are_off_by_default_and_within_chains() -> None:
    kfs, _, _ = _biased_chain(6)
    assert planar_edges(kfs, T_BASE_CAMERA, SlamPlanarParams()) == []
    for kf in kfs[3:]:
        kf.chain = 1  # a new chain starts at keyframe 3: no planar edge joins 2 and 3
    pairs = [(e.a, e.b) for e in planar_edges(kfs, T_BASE_CAMERA, SlamPlanarParams(enabled=True))]
    assert pairs == [(0, 1), (1, 2), (3, 4), (4, 5)]



def test_a_level_floor_stops_a_climb_the_steps_allow() -> None:
    # visual-like edges 2 mm too high and 0.05 deg pitched per step, surer than the gait's bob:
    # consecutive planar edges give way a little at every step and the chain climbs; held level
    # in the map frame it cannot, and the motion in the plane is left to the edges
    n = 100
    T_base = lap_poses(n, 1.8, 0.9)
    cams = T_base @ T_BASE_CAMERA
    T_cb = invert(T_BASE_CAMERA)
    bias = make_T(so3_exp(np.array([0.0, np.radians(0.05), 0.0])), np.array([0.0, 0.0, 0.002]))
    cov = np.diag([np.radians(0.1) ** 2] * 3 + [0.002**2] * 3)
    edges, T_init = [], [cams[0]]
    for i in range(n - 1):
        M = invert(T_base[i]) @ T_base[i + 1]
        edges.append(Edge(i, i + 1, T_cb @ M @ bias @ T_BASE_CAMERA, cov, "visual"))
        T_init.append(T_init[-1] @ edges[-1].T_a_b)
    kfs = [SimpleNamespace(id=i, chain=0, T_init=T) for i, T in enumerate(T_init)]
    graph = SlamGraphParams()
    steps = edges + planar_edges(kfs, T_BASE_CAMERA, SlamPlanarParams(enabled=True))
    floor = floor_of(cams[0], T_BASE_CAMERA, (0.0, 0.0, 1.0), 0.01, float(np.radians(0.5)))
    free = _bases(optimise(kfs, steps, cams[0], graph).poses)
    held = _bases(optimise(kfs, steps, cams[0], graph, floor).poses)
    assert np.abs(free[:, 2, 3]).max() > 0.1 and np.abs(held[:, 2, 3]).max() < 0.01
    def tilt(b: np.ndarray) -> float:
        return float(np.degrees(np.arccos(np.clip(b[:, 2, 2], -1, 1))).max())

    assert tilt(free) > 1.0 and tilt(held) < 0.5  # within the gait's bob
    # yaw and x, y are free: the biased edges, now contradicted, move them by a compromise only
    true_xy = T_base[:, :2, 3]
    assert np.abs(held[:, :2, 3] - true_xy).max() <= np.abs(free[:, :2, 3] - true_xy).max() + 0.02


def test_visual_covariance_scale_weighs_the_visual_edge_down() -> None:
    # one step: odometry says 1.00 m ahead, a visual edge with the same noise 1.10 m
    kfs = [SimpleNamespace(id=i, chain=0, T_init=make_T(np.eye(3), np.array([0.0, 0.0, float(i)]))) for i in (0, 1)]
    cov = np.diag([1e-4] * 3 + [1e-4] * 3)
    edges = [Edge(0, 1, make_T(np.eye(3), np.array([0.0, 0.0, 1.0])), cov, "odometry"),
             Edge(0, 1, make_T(np.eye(3), np.array([0.0, 0.0, 1.1])), cov, "visual")]
    ahead = {s: optimise(kfs, edges, np.eye(4), SlamGraphParams(visual_covariance_scale=s)).poses[1][2, 3]
             for s in (1.0, 4.0)}
    assert abs(ahead[1.0] - 1.05) < 1e-3 and abs(ahead[4.0] - 1.02) < 1e-3
