from __future__ import annotations

import numpy as np
import pytest

from litevloc.base import geometry as g
from litevloc.base.params.mapping import KeyframeParams
from litevloc.pipelines.topomap.keyframes import (
    band_keys,
    budget_binds,
    coverage_keys,
    coverage_keys_sliced,
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
    from litevloc.base.params.mapping import ConnectivityParams
    from litevloc.pipelines.topomap.graphs import build_connectivity
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


def _plain_greedy(cover: list[np.ndarray], params: KeyframeParams) -> list[int]:
    """The textbook greedy (re-evaluates every candidate each round) as the reference."""
    covered: set[int] = set()
    universe = set(np.concatenate(cover).tolist())
    sel: list[int] = []
    while len(sel) < (params.budget or len(cover)):
        gains = [len(set(c.tolist()) - covered) if i not in sel else -1 for i, c in enumerate(cover)]
        best = int(np.argmax(gains))  # first maximum = earliest candidate
        if gains[best] < params.min_gain:
            break
        sel.append(best)
        covered |= set(cover[best].tolist())
        if len(covered) / len(universe) >= params.coverage:
            break
    return sel


def test_lazy_greedy_picks_what_plain_greedy_picks() -> None:
    rng = np.random.default_rng(0)
    for trial in range(20):
        cover = [np.unique(rng.integers(0, 300, rng.integers(1, 40))) for _ in range(60)]
        for params in (KeyframeParams(coverage=0.95), KeyframeParams(coverage=1.0, budget=7)):
            sel, hist = greedy_select(cover, params)
            assert sel == _plain_greedy(cover, params), trial
            assert np.all(np.diff(hist) > 0)


def test_no_budget_means_coverage_decides_and_binding_cap_is_reported() -> None:
    cover = [np.array([i]) for i in range(100)]  # every candidate adds one new key
    sel, hist = greedy_select(cover, KeyframeParams(coverage=0.95))
    assert len(sel) == 95 and not budget_binds(len(sel), hist, KeyframeParams(coverage=0.95))
    capped = KeyframeParams(coverage=0.95, budget=10)
    sel, hist = greedy_select(cover, capped)
    assert len(sel) == 10 and budget_binds(len(sel), hist, capped)
    # a cap that is not reached does not bind
    roomy = KeyframeParams(coverage=0.95, budget=200)
    sel, hist = greedy_select(cover, roomy)
    assert len(sel) == 95 and not budget_binds(len(sel), hist, roomy)


def test_sliced_keys_with_band_equal_plain_keys() -> None:
    rng = np.random.default_rng(1)
    up = np.array([0.0, 0, 1])
    params = KeyframeParams(cell_m=0.5, heading_bins=8, height_band_m=(-0.4, 2.5))
    # heights kept clear of the band edges (ref 0.5: band [0.1, 3.0]) by more than half a slice
    z = np.concatenate([rng.uniform(-1.0, 0.0, 300), rng.uniform(0.2, 2.9, 600), rng.uniform(3.1, 4.0, 100)])
    pts = np.column_stack([rng.uniform(-5, 5, len(z)), rng.uniform(-5, 5, len(z)), z])
    cam = np.array([0.3, -0.2, 0.5])
    plain = coverage_keys(pts, cam, up, 0.5, params)
    banded = band_keys(coverage_keys_sliced(pts, cam, up, params), 0.5, params)
    assert len(plain) > 50 and np.array_equal(plain, banded)
