"""Two-pass streaming build: models run on keyframes only; memory bounded by the place."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest

from litevloc.base import geometry as g
from litevloc.base.params.mapping import KeyframeParams, MappingParams
from litevloc.pipelines.topomap.build import MapBuilder, PosedFrame, build_two_pass

from .helpers import orb_extract as _orb
from .helpers import orb_match, thumb_describe

K = np.array([[100.0, 0, 80], [0, 100.0, 60], [0, 0, 1]])


def _frames(n_laps: int) -> Iterator[PosedFrame]:
    """A camera (z-up world, optical axis level) turning on the spot in a 4 m square room, n laps."""
    rng = np.random.default_rng(0)
    img = rng.integers(0, 255, (120, 160, 3), dtype=np.uint8)
    i = 0
    for _ in range(n_laps):
        for yaw in np.radians(np.arange(0, 360, 6)):
            R_wv = np.array([[0, 0, 1], [-1, 0, 0], [0, -1, 0]], float)  # camera looking along +x
            T = g.make_T(g.so3_exp(np.array([0, 0, yaw])) @ R_wv, [0.0, 0.0, 0.5])
            depth = np.full((120, 160), 2.0 / max(abs(np.cos(yaw % (np.pi / 2) - np.pi / 4)), 0.5), np.float32)
            yield i * 10_000_000, img, depth, K, T, i, None
            i += 1


def _builder(calls: list[int], budget: int | None = None) -> MapBuilder:
    def extract(im: np.ndarray):  # counts model calls
        calls.append(1)
        return _orb(im)

    kp = KeyframeParams(min_translation_m=0.1, min_rotation_deg=10, budget=budget, cell_m=0.5,
                        height_band_m=(-0.4, 2.5), max_depth_m=6.0, pixel_stride=8)
    return MapBuilder(MappingParams(keyframes=kp), extract, thumb_describe, orb_match, "orb", "thumb")


def test_models_run_on_keyframes_only_and_memory_does_not_grow_with_laps() -> None:
    calls1: list[int] = []
    b1 = _builder(calls1)
    m1 = build_two_pass(b1, lambda _c: _frames(1))
    assert len(calls1) == m1.n_nodes < b1.report.candidates
    calls3: list[int] = []
    b3 = _builder(calls3)
    m3 = build_two_pass(b3, lambda _c: _frames(3))
    # three laps over the same place: same keyframe count, the occupancy accumulator does not grow
    assert m3.n_nodes == m1.n_nodes and len(calls3) == m3.n_nodes
    assert b3.report.voxel_bytes == b1.report.voxel_bytes
    assert b3.report.candidates == b1.report.candidates and b3.report.skipped["revisit (near-duplicate candidate)"] > 0
    assert not b1.report.budget_bound and b1.report.coverage >= 0.95


def test_binding_budget_is_reported_and_missing_pass2_is_an_error() -> None:
    b = _builder([], budget=2)
    m = build_two_pass(b, lambda _c: _frames(1))
    assert m.n_nodes == 2 and b.report.budget_bound and b.report.coverage < 0.95
    b2 = _builder([])
    for f in _frames(1):
        b2.add(*f)
    with pytest.raises(ValueError, match="pass 2 never delivered"):
        b2.finish()


def test_pose_only_frames_give_the_same_map_as_full_frames() -> None:
    """A source may render depth only where `is_candidate` says so (`add_pose` elsewhere)."""
    full = _builder([])
    m_full = build_two_pass(full, lambda _c: _frames(1))
    lazy = _builder([])
    for t, _c, depth, K_, T, i, _j in _frames(1):
        if lazy.is_candidate(T):
            lazy.add(t, None, depth, K_, T, i)
        else:
            lazy.add_pose(T, i)
    for pos in sorted(lazy.wanted().values()):
        f = list(_frames(1))[lazy.candidates[pos].index]
        lazy.attach(pos, f[1], f[2])
    m_lazy = lazy.finish()
    assert lazy.report.frames == full.report.frames and lazy.report.candidates == full.report.candidates
    np.testing.assert_array_equal(m_lazy.frame_index, m_full.frame_index)
    np.testing.assert_array_equal(m_lazy.grid.cells, m_full.grid.cells)


def test_stored_keypoints_keeps_the_strongest_with_their_depth() -> None:
    import dataclasses

    full = build_two_pass(_builder([]), lambda _c: _frames(1))
    b = _builder([])
    b.params = dataclasses.replace(b.params, stored_keypoints=40)
    small = build_two_pass(b, lambda _c: _frames(1))
    assert small.n_nodes == full.n_nodes
    for f_all, f in zip(full.features, small.features, strict=True):
        n = min(40, len(f_all.keypoints))
        assert len(f.keypoints) == n and f.depth is not None and len(f.depth) == n
        # the kept ones are the strongest, in their original order
        assert np.sort(f.scores)[0] >= np.sort(f_all.scores)[::-1][n - 1]
        idx = [int(np.flatnonzero((f_all.keypoints == kp).all(axis=1))[0]) for kp in f.keypoints]
        assert idx == sorted(idx)
    with pytest.raises(ValueError, match="stored_keypoints"):
        MappingParams(stored_keypoints=-1)
