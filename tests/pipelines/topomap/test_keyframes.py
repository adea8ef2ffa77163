from __future__ import annotations

import numpy as np
import pytest

from litevloc.pipelines import geometry as g
from litevloc.pipelines.topomap.keyframes import (
    KeyframeParams,
    coverage_keys,
    greedy_select,
    motion_prefilter,
    plane_axes,
)


def test_motion_prefilter_thresholds() -> None:
    T = np.stack([g.make_T(np.eye(3), [0.04 * i, 0, 0]) for i in range(10)])
    kept = motion_prefilter(T, KeyframeParams(min_translation_m=0.1, min_rotation_deg=100))
    assert kept == [0, 3, 6, 9]
    R = np.stack([g.make_T(g.so3_exp(np.array([0, 0, np.radians(2.0 * i)])), [0, 0, 0]) for i in range(6)])
    assert motion_prefilter(R, KeyframeParams(min_translation_m=1, min_rotation_deg=3)) == [0, 2, 4]


def test_greedy_selection_is_max_coverage_and_stops() -> None:
    cover = [np.array([1, 2, 3]), np.array([3, 4]), np.array([1, 2, 3, 4, 5, 6]), np.array([7])]
    sel, hist = greedy_select(cover, KeyframeParams(budget=10, coverage=1.0))
    assert sel == [2, 3] and hist[-1] == 1.0
    sel, hist = greedy_select(cover, KeyframeParams(budget=1, coverage=1.0))
    assert sel == [2] and np.isclose(hist[0], 6 / 7)
    sel, _ = greedy_select(cover, KeyframeParams(budget=10, coverage=0.8))
    assert sel == [2]
    # ties broken by the earliest candidate (deterministic)
    sel, _ = greedy_select([np.array([1]), np.array([2])], KeyframeParams(budget=1, coverage=1.0))
    assert sel == [0]


def test_coverage_keys_distinguish_viewing_direction() -> None:
    up = np.array([0.0, 0, 1])
    wall = np.array([[1.0 + 0.01 * i, 0.0, 0.5] for i in range(5)])
    params = KeyframeParams(cell_m=0.5, heading_bins=8)
    a = coverage_keys(wall, np.array([0.0, 0, 0.5]), up, 0.5, params)
    b = coverage_keys(wall, np.array([3.0, 0, 0.5]), up, 0.5, params)
    assert len(a) == 1 and len(b) == 1 and a[0] != b[0]  # same cell, opposite sides
    one_bin = KeyframeParams(cell_m=0.5, heading_bins=1)
    assert np.array_equal(coverage_keys(wall, np.zeros(3), up, 0.5, one_bin),
                          coverage_keys(wall, np.array([3.0, 0, 0]), up, 0.5, one_bin))
    high = wall + np.array([0, 0, 5.0])  # outside the height band
    assert len(coverage_keys(high, np.zeros(3), up, 0.5, params)) == 0


def test_plane_axes_orthonormal() -> None:
    for up in ([0, 0, 1], [0.01, -0.9, -0.43], [1, 0, 0]):
        u = np.asarray(up, float) / np.linalg.norm(up)
        A = plane_axes(u)
        assert np.allclose(A @ A.T, np.eye(2)) and np.allclose(A @ u, 0)


def test_params_validation() -> None:
    with pytest.raises(ValueError, match="budget"):
        KeyframeParams(budget=0)
    with pytest.raises(ValueError, match="height_band"):
        KeyframeParams(height_band_m=(1.0, -1.0))


def test_connectivity_keeps_nearest_line_of_sight_partners() -> None:
    from litevloc.pipelines.topomap.graphs import ConnectivityParams, build_connectivity
    from litevloc.pipelines.topomap.types import OccupancyGrid

    # 10 keyframes on a line 0.1 m apart, all in free space: consecutive ones are always
    # connected; line-of-sight edges are limited to each node's 2 nearest partners.
    traj = np.array([[0.1 * i, 0.0, 0.0] for i in range(10)])
    grid = OccupancyGrid(np.ones((20, 20), np.uint8), np.array([-0.5, -0.5]), 0.1, np.array([0, 0, 1.0]),
                         plane_axes(np.array([0, 0, 1.0])))
    e, w = build_connectivity(np.arange(10), traj, grid, ConnectivityParams(2.0, max_line_of_sight_neighbours=2))
    pairs = {tuple(p) for p in e.tolist()}
    assert {(k, k + 1) for k in range(9)} <= pairs
    assert all(abs(i - j) <= 2 for i, j in pairs) and (0, 2) in pairs and (0, 9) not in pairs
    assert np.allclose(w[[list(p) == [0, 1] for p in e.tolist()]], 0.1)
