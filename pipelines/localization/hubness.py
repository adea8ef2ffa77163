"""Hubness of map keyframes in place recognition: how much a keyframe's VPR descriptor resembles
other places.

A generic view (a corridor of repeated tiles and pillars, a blank wall) is similar to many
places; under a change of lighting such keyframes can crowd GL's top-k for unrelated frames.
The hubness of keyframe d is the mean cosine similarity to its k most similar keyframes farther
than `exclude_m` (its own place's keyframes are rightly similar). GL may rank by similarity less
a multiple of it (`global_search.hub_penalty`), as cross-domain similarity local scaling (CSLS)
does for nearest-neighbour retrieval.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

BLOCK = 1024  # rows of the similarity matrix held at once: memory O(BLOCK x N), not O(N^2)


def hubness(vpr: NDArray[np.floating], positions: NDArray[np.floating], k: int,
            exclude_m: float) -> NDArray[np.float32]:
    """(N,) mean cosine similarity of each keyframe's descriptor (`vpr`, (N, D), unit rows) to
    its `k` most similar keyframes at least `exclude_m` metres away (`positions`, (N, 3), map
    frame); fewer such keyframes: the mean of those there are; none: 0."""
    v = np.asarray(vpr, np.float32)
    pos = np.asarray(positions, np.float64)
    n = len(v)
    out = np.zeros(n, np.float32)
    if n == 0 or k <= 0:
        return out
    for lo in range(0, n, BLOCK):
        hi = min(lo + BLOCK, n)
        sims = v[lo:hi] @ v.T
        d2 = (pos[lo:hi] ** 2).sum(1)[:, None] + (pos ** 2).sum(1)[None, :] - 2.0 * pos[lo:hi] @ pos.T
        far = d2 >= exclude_m**2
        sims = np.where(far, sims, -np.inf)
        kk = min(k, n)
        top = -np.partition(-sims, kk - 1, axis=1)[:, :kk]
        finite = np.isfinite(top)
        count = finite.sum(axis=1)
        total = np.where(finite, top, 0.0).sum(axis=1)
        out[lo:hi] = np.where(count > 0, total / np.maximum(count, 1), 0.0)
    return out
