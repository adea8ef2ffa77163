"""Descriptor-only helpers of `pipelines.guided_matching` (no poses, no model)."""

from __future__ import annotations

import numpy as np

from litevloc.pipelines.guided_matching import mutual_nn_count


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
