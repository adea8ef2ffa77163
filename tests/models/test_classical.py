"""Classical baselines (SIFT, ORB with NN + ratio) and the mutual-NN matcher."""

from __future__ import annotations

import numpy as np
import pytest

from litevloc.models.classical import MutualNNMatcher, OpenCVExtractor, RatioMatcher
from litevloc.models.types import Features


def _feats(desc: np.ndarray) -> Features:
    n = desc.shape[0]
    return Features(np.zeros((n, 2), np.float32), desc, np.ones(n, np.float32), (64, 48))


def test_mnn_and_ratio_recover_a_permutation() -> None:
    rng = np.random.default_rng(0)
    d0 = rng.normal(size=(50, 32)).astype(np.float32)
    d0 /= np.linalg.norm(d0, axis=1, keepdims=True)
    perm = rng.permutation(50)
    d1 = d0[perm] + 0.01 * rng.normal(size=(50, 32)).astype(np.float32)
    d1 /= np.linalg.norm(d1, axis=1, keepdims=True)
    inv = np.argsort(perm)
    for matcher in (MutualNNMatcher(), RatioMatcher(0.8)):
        m = matcher.match(_feats(d0), _feats(d1))
        assert len(m) == 50 and m.idx0.dtype == np.int64
        np.testing.assert_array_equal(m.idx1, inv[m.idx0])
        assert ((m.scores > 0.9) & (m.scores <= 1.0)).all()


def test_ratio_rejects_ambiguous_and_mnn_is_mutual() -> None:
    d0 = np.array([[1.0, 0.1], [0.0, 1.0]], np.float32)
    d1 = np.array([[1.0, 0.0], [1.0, 0.2]], np.float32)  # row 0 of d0 lies between both
    d0 /= np.linalg.norm(d0, axis=1, keepdims=True)
    d1 /= np.linalg.norm(d1, axis=1, keepdims=True)
    m = RatioMatcher(0.8).match(_feats(d0), _feats(d1))
    assert 0 not in m.idx0  # row 0 is ambiguous
    mm = MutualNNMatcher().match(_feats(d0), _feats(d1))
    pairs = set(zip(mm.idx0.tolist(), mm.idx1.tolist(), strict=True))
    assert (0, 1) in pairs and len(set(mm.idx1.tolist())) == len(mm)


def test_binary_descriptors_use_hamming() -> None:
    rng = np.random.default_rng(2)
    d0 = rng.integers(0, 256, (20, 32), dtype=np.uint8)
    d1 = d0[::-1].copy()
    d1[:, 0] ^= 1  # one bit differs
    m = MutualNNMatcher().match(_feats(d0), _feats(d1))
    np.testing.assert_array_equal(m.idx1, 19 - m.idx0)
    assert len(m) == 20 and np.allclose(m.scores, 1 - 1 / 256)
    with pytest.raises(ValueError, match="descriptor mismatch"):
        MutualNNMatcher().match(_feats(d0), _feats(np.zeros((3, 32), np.float32)))


@pytest.mark.parametrize("name", ["sift", "orb"])
def test_opencv_extractors_on_real_pair(name: str, frame_rgb) -> None:  # type: ignore[no-untyped-def]
    ex = OpenCVExtractor(name, (480, 640), max_keypoints=500)
    f0, f1 = ex.extract(frame_rgb(0)), ex.extract(frame_rgb(15))
    assert 100 < len(f0) <= 500 and f0.image_size == (640, 480)
    if name == "sift":
        assert f0.descriptors.dtype == np.float32 and f0.descriptors.shape[1] == 128
        np.testing.assert_allclose(np.linalg.norm(f0.descriptors, axis=1), 1, atol=1e-5)
    else:
        assert f0.descriptors.dtype == np.uint8 and f0.descriptors.shape[1] == 32
    m = RatioMatcher(0.8).match(f0, f1)
    # frames 0 and 15 are 1.5 cm apart: most matches move by only a few pixels
    flow = np.linalg.norm(f0.keypoints[m.idx0] - f1.keypoints[m.idx1], axis=1)
    assert len(m) > 50 and np.median(flow) < 15


def test_empty_inputs_give_empty_matches() -> None:
    e = _feats(np.zeros((0, 8), np.float32))
    f = _feats(np.full((4, 8), 1 / np.sqrt(8), np.float32))
    assert len(MutualNNMatcher().match(e, f)) == 0 and len(RatioMatcher().match(f, e)) == 0
    blank = OpenCVExtractor("orb", (48, 64)).extract(np.zeros((48, 64, 3), np.uint8))
    assert len(blank) == 0 and blank.descriptors.shape == (0, 32)
