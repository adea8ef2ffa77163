"""Descriptor-only helpers of `pipelines.guided_matching` (no poses, no model)."""

from __future__ import annotations

import numpy as np

from litevloc.pipelines.guided_matching import match_by_projection, mutual_nn_count, mutual_nn_pairs


def test_mutual_nn_count_counts_shared_descriptors_above_the_floor() -> None:
    rng = np.random.default_rng(0)
    a = rng.normal(size=(200, 32)).astype(np.float32)
    b = np.vstack([a[:50] + 0.05 * rng.normal(size=(50, 32)), rng.normal(size=(150, 32))]).astype(np.float32)
    # the 50 shared descriptors are each other's mutual best, near 1.0 in cosine
    assert 50 <= mutual_nn_count(a, b, 0.9) <= 52
    # with no floor, random pairs that happen to be mutual best count too
    assert mutual_nn_count(a, b, -1.0) > mutual_nn_count(a, b, 0.9)
    assert mutual_nn_count(a, b, 1.0) == 0
    assert mutual_nn_count(a[:0], b, 0.0) == 0 and mutual_nn_count(a, b[:0], 0.0) == 0


def test_mutual_nn_count_on_binary_descriptors() -> None:
    rng = np.random.default_rng(1)
    a = rng.integers(0, 256, size=(100, 32), dtype=np.uint8)
    b = np.vstack([a[:30], rng.integers(0, 256, size=(70, 32), dtype=np.uint8)])
    assert mutual_nn_count(a, b, 0.99) == 30  # identical bit strings: similarity 1


def _reference_mutual(a: np.ndarray, b: np.ndarray, floor: float) -> tuple[np.ndarray, np.ndarray]:
    """Mutual nearest neighbours by the two plain argmaxes, in float64."""
    an = a / np.linalg.norm(a, axis=1, keepdims=True)
    bn = b / np.linalg.norm(b, axis=1, keepdims=True)
    S = np.asarray(an @ bn.T, dtype=np.float64)
    best_b, best_a = S.argmax(axis=1), S.argmax(axis=0)
    rows = np.arange(len(a))
    keep = (best_a[best_b] == rows) & (S[rows, best_b] >= floor)
    return rows[keep], best_b[keep]


def test_mutual_pairs_equal_the_two_argmaxes_with_ties_and_at_the_floor() -> None:
    rng = np.random.default_rng(2)
    a = rng.normal(size=(300, 16)).astype(np.float32)
    b = np.vstack([a[:60] + 0.02 * rng.normal(size=(60, 16)), rng.normal(size=(200, 16))]).astype(np.float32)
    a[100:103] = a[5]  # three live rows tie for keyframe row 5's column: argmax takes the first
    b[250] = b[7]  # and two keyframe columns tie for a row
    for floor in (-1.0, 0.5, 0.9, 0.99):
        ra, ca = mutual_nn_pairs(a, b, floor)
        rb, cb = _reference_mutual(a, b, floor)
        assert np.array_equal(ra, rb) and np.array_equal(ca, cb), floor
    # the floor compares in float64: a pair exactly at a float32 similarity is kept, one above it dropped
    r, c = mutual_nn_pairs(a, b, -1.0)
    an = a / np.linalg.norm(a, axis=1, keepdims=True)
    bn = b / np.linalg.norm(b, axis=1, keepdims=True)
    s = float((an @ bn.T)[r[0], c[0]])
    assert r[0] in mutual_nn_pairs(a, b, s)[0] and r[0] not in mutual_nn_pairs(a, b, np.nextafter(s, 2.0))[0]


def test_match_by_projection_global_mutual_keeps_only_global_mutual_pairs() -> None:
    rng = np.random.default_rng(3)
    n = 400
    pts = np.column_stack([rng.uniform(-1, 1, n), rng.uniform(-0.7, 0.7, n), rng.uniform(2, 4, n)])
    K = np.array([[300.0, 0, 160], [0, 300, 120], [0, 0, 1]])
    uv = pts[:, :2] / pts[:, 2:] * 300 + [160, 120]
    desc = rng.normal(size=(n, 32)).astype(np.float32)
    kf_desc = (desc + 1.0 * rng.normal(size=(n, 32))).astype(np.float32)
    kf_desc[10] = kf_desc[11]  # a tie in the keyframe
    eye = np.eye(4)
    li, ki = match_by_projection(pts, desc, eye, uv + rng.normal(0, 1, (n, 2)), kf_desc, K, eye, 40.0, 0.0, True)
    ra, ca = _reference_mutual(desc, kf_desc, 0.0)
    mutual = set(zip(ra.tolist(), ca.tolist(), strict=True))
    pairs = set(zip(li.tolist(), ki.tolist(), strict=True))
    assert len(pairs) > 100 and pairs <= mutual


def test_mutual_pairs_of_binary_descriptors_resolve_their_many_ties_as_argmax_does() -> None:
    rng = np.random.default_rng(5)
    for _ in range(10):  # 32-bit strings: 33 similarity values, ties in most columns
        a = rng.integers(0, 256, size=(300, 4), dtype=np.uint8)
        b = rng.integers(0, 256, size=(280, 4), dtype=np.uint8)
        bits_a = np.unpackbits(a, axis=1).astype(np.float64)
        bits_b = np.unpackbits(b, axis=1).astype(np.float64)
        S = 1.0 - 2.0 * (bits_a[:, None, :] != bits_b[None, :, :]).mean(axis=2)
        best_b, best_a = S.argmax(axis=1), S.argmax(axis=0)
        rows = np.arange(len(a))
        keep = (best_a[best_b] == rows) & (S[rows, best_b] >= 0.0)
        got = mutual_nn_pairs(a, b, 0.0)
        assert np.array_equal(got[0], rows[keep]) and np.array_equal(got[1], best_b[keep])
