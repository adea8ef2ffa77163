"""The model-output comparison both runtime checks use (`experiments/model_conformance.py`):
keypoints paired by position with top-k ties told apart, floats within tolerance, match indices by
agreement, and the worker's files without pickle."""

from __future__ import annotations

import numpy as np
import pytest

from litevloc.experiments import model_conformance as mc


def _features(rng: np.random.Generator, k: int = 64) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    kpts = rng.uniform(0, 300, (k, 2)).astype(np.float32)
    desc = rng.normal(size=(k, 16)).astype(np.float32)
    desc /= np.linalg.norm(desc, axis=1, keepdims=True)
    scores = np.sort(rng.uniform(0.2, 1.0, k)).astype(np.float32)[::-1].copy()
    return kpts, desc, scores


def test_keypoints_are_paired_by_position_and_ties_at_the_cut_pass() -> None:
    k, d, s = _features(np.random.default_rng(0))
    order = np.random.default_rng(1).permutation(len(k))  # another order of the same keypoints
    same = mc.compare_outputs("aliked", "extractor", ["kpts", "desc", "scores"], [k, d, s],
                               [k[order], d[order] + 1e-7, s[order]])
    assert [x.output for x in same] == ["keypoints", "descriptors", "scores"] and all(x.passed for x in same)
    assert same[0].agree == 1.0
    # the last kept keypoint swapped for another with the same score (a top-k tie): still agrees
    k2, s2 = k.copy(), s.copy()
    k2[-1] = [301.0, 301.0]
    tie = mc.compare_outputs("aliked", "extractor", ["kpts", "desc", "scores"], [k, d, s], [k2, d, s2])
    assert tie[0].passed and tie[0].agree == pytest.approx(63 / 64) and "unpaired" in tie[0].note
    # the strongest keypoint moved: not a tie, the check fails
    k3 = k.copy()
    k3[0] += 0.5
    moved = mc.compare_outputs("aliked", "extractor", ["kpts", "desc", "scores"], [k, d, s], [k3, d, s])
    assert not moved[0].passed
    # a descriptor off by 0.01 (a wrong kernel would be far more): fails
    d4 = d.copy()
    d4[5, 3] += 0.01
    bad = mc.compare_outputs("aliked", "extractor", ["kpts", "desc", "scores"], [k, d, s], [k, d4, s])
    assert bad[0].passed and not bad[1].passed and bad[1].max_abs == pytest.approx(0.01, rel=1e-3)


def test_float_and_index_outputs() -> None:
    rng = np.random.default_rng(2)
    x = rng.normal(scale=10.0, size=(1, 200, 64)).astype(np.float32)
    m = rng.integers(-1, 200, (1, 200)).astype(np.int64)
    close = mc.compare_outputs("layer0", "matcher-part", ["d0", "m0"], [x, m], [x * (1 + 1e-5), m])
    assert all(c.passed for c in close) and close[0].scale == pytest.approx(float(np.abs(x).max()))
    far = mc.compare_outputs("layer0", "matcher-part", ["d0"], [x], [x + 0.1 * float(np.abs(x).max())])
    assert not far[0].passed
    m1 = m.copy()
    m1[0, :1] = -2  # 1 of 200 matches differs: 99.5 % agree
    m3 = m.copy()
    m3[0, :3] = -2  # 3 of 200: 98.5 %
    assert mc.compare_outputs("head", "matcher", ["m0"], [m], [m1])[0].passed
    assert not mc.compare_outputs("head", "matcher", ["m0"], [m], [m3])[0].passed
    nan = x.copy()
    nan[0, 0, 0] = np.nan
    assert not mc.compare_outputs("l", "matcher-part", ["d0"], [x], [nan])[0].passed
    assert not mc.compare_outputs("l", "matcher-part", ["d0"], [x], [x[:, :100]])[0].passed
    assert not mc.compare_outputs("l", "matcher-part", ["d0", "d1"], [x, x], [x])[0].passed


def test_worker_files_round_trip_without_pickle(tmp_path) -> None:  # type: ignore[no-untyped-def]
    mc.save_npz(tmp_path / "m.npz", {"a": np.arange(3), "b": np.ones((2, 2), np.float32)})
    back = mc.load_npz(tmp_path / "m.npz")
    assert set(back) == {"a", "b"} and back["b"].dtype == np.float32
