"""Product quantiser of map descriptors: nearest centroids, reproducible codebooks, layouts."""

from __future__ import annotations

import numpy as np
import pytest

from litevloc.pipelines.topomap.descriptor_codec import (
    MAX_CENTROIDS,
    check_layout,
    decode,
    encode,
    train,
    training_rows,
)


def clustered_descriptors(n: int, dim: int = 128, seed: int = 0) -> np.ndarray:
    """Unit descriptors around 64 centres (learned descriptors are far from uniform on the sphere)."""
    rng = np.random.default_rng(seed)
    centres = rng.normal(size=(64, dim))
    x = centres[rng.integers(0, 64, n)] + rng.normal(scale=0.35, size=(n, dim))
    return (x / np.linalg.norm(x, axis=1, keepdims=True)).astype(np.float32)


def test_codes_are_the_nearest_centroids_and_decode_to_unit_vectors() -> None:
    x = clustered_descriptors(3000)
    book = train(x, 32)
    assert book.shape == (32, MAX_CENTROIDS, 4) and book.dtype == np.float32
    codes = encode(x, book)
    assert codes.shape == (3000, 32) and codes.dtype == np.uint8
    # brute force over every centroid of every sub-space
    sub = x.reshape(3000, 32, 1, 4)
    brute = np.argmin(((sub - book[None]) ** 2).sum(axis=3), axis=2)
    assert np.mean(brute == codes) > 0.999  # ties at float precision aside
    y = decode(codes, book)
    np.testing.assert_allclose(np.linalg.norm(y, axis=1), 1.0, atol=1e-5)
    cos = np.sum(x * y, axis=1)
    assert float(np.median(cos)) > 0.95
    # and better than any codebook would do: centroids drawn at random from the data
    rand = x[np.random.default_rng(1).choice(3000, MAX_CENTROIDS, replace=False)].reshape(MAX_CENTROIDS, 32, 4)
    rand_cos = np.sum(x * decode(encode(x, rand.transpose(1, 0, 2).copy()), rand.transpose(1, 0, 2).copy()), axis=1)
    assert float(np.median(cos)) > float(np.median(rand_cos)) + 0.01


def test_training_is_reproducible() -> None:
    x = clustered_descriptors(2000, seed=3)
    np.testing.assert_array_equal(train(x, 16), train(x, 16))
    rows = training_rows([500, 0, 20000, 7], 1000)
    assert len(rows) == 1000 and np.all(np.diff(rows) > 0) and rows.max() < 20507
    np.testing.assert_array_equal(rows, training_rows([500, 0, 20000, 7], 1000))
    np.testing.assert_array_equal(training_rows([3, 4], 1000), np.arange(7))


def test_small_and_empty_samples() -> None:
    x = clustered_descriptors(40, dim=16)
    book = train(x, 4)
    assert book.shape == (4, 40, 4)  # fewer rows than 256 centroids: one per row
    np.testing.assert_allclose(decode(encode(x, book), book), x, atol=1e-5)  # each row is its own centroid
    empty = train(np.zeros((0, 16), np.float32), 4)
    assert empty.shape == (4, 1, 4)
    assert decode(np.zeros((0, 4), np.uint8), empty).shape == (0, 16)


def test_layout_errors_name_the_problem() -> None:
    with pytest.raises(ValueError, match="divisible"):
        check_layout(128, 24)
    with pytest.raises(ValueError, match="divisible"):
        train(clustered_descriptors(300), 48)
    book = train(clustered_descriptors(300), 32)
    with pytest.raises(ValueError, match=r"descriptors must be \(M, 128\)"):
        encode(np.zeros((3, 64), np.float32), book)
    with pytest.raises(ValueError, match=r"codes must be \(M, 32\)"):
        decode(np.zeros((3, 16), np.uint8), book)
