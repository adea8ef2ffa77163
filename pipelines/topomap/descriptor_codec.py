"""Product quantisation of a map's local descriptors (the compact map format, #15).

A D-dimensional float descriptor is cut into S sub-vectors of D/S dimensions; each
sub-vector is stored as the 8-bit index of its nearest centroid in that sub-space's
codebook (K <= 256 centroids, trained per map by k-means on a sample of the map's own
descriptors). A 128-d ALIKED descriptor with S = 32 costs 32 bytes instead of 132 for int8
codes + a scale (map format 2) or 512 as float32; decoded descriptors are the concatenated
centroids, renormalised to unit length (the extractors' descriptors are unit vectors).

k-means is OpenCV's (`cv2.kmeans`, k-means++ seeding, a fixed RNG seed: the same map
gives the same codebook and codes, byte for byte). The encoder's nearest-centroid search
is one matrix product per sub-space and chunk of rows.

Arrays: codebook (S, K, D/S) float32; codes (M, S) uint8, every code < K.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
from numpy.typing import NDArray

MAX_CENTROIDS = 256  # one byte per sub-vector
TRAIN_ROWS = 16384  # descriptors sampled to train a codebook (more changes the codebook little, costs linearly)
KMEANS_ITERATIONS = 10
_CHUNK = 16384  # rows per nearest-centroid product (16384 x 256 float32 = 16 MB)
_SEED = 0


def check_layout(dim: int, n_sub: int) -> None:
    """ValueError unless `n_sub` sub-vectors evenly split a `dim`-dimensional descriptor."""
    if n_sub < 1 or dim < 1 or dim % n_sub:
        raise ValueError(f"a product quantiser with {n_sub} sub-vectors needs a descriptor dimension divisible by "
                         f"it, got {dim}")


def training_rows(counts: Iterable[int], n_rows: int = TRAIN_ROWS) -> NDArray[np.int64]:
    """Sorted global row indices of an evenly spread, seeded sample of at most `n_rows` of
    the rows of consecutive blocks of `counts` rows (nodes): what `train` should see."""
    total = int(sum(int(c) for c in counts))
    if total <= n_rows:
        return np.arange(total, dtype=np.int64)
    rng = np.random.default_rng(_SEED)
    return np.sort(rng.choice(total, n_rows, replace=False)).astype(np.int64)


def train(sample: NDArray[np.floating], n_sub: int) -> NDArray[np.float32]:
    """(R, D) descriptor sample -> (S, K, D/S) float32 codebook, K = min(256, R) (K = 1,
    a zero centroid, for an empty sample)."""
    import cv2  # here: loading a map (decode) needs no OpenCV

    x = np.ascontiguousarray(sample, dtype=np.float32)
    if x.ndim != 2:
        raise ValueError(f"descriptor sample must be (R, D), got shape {x.shape}")
    check_layout(x.shape[1], n_sub)
    d = x.shape[1] // n_sub
    k = min(MAX_CENTROIDS, len(x))
    if k == 0:
        return np.zeros((n_sub, 1, d), np.float32)
    criteria = (cv2.TERM_CRITERIA_MAX_ITER + cv2.TERM_CRITERIA_EPS, KMEANS_ITERATIONS, 1e-6)
    book = np.empty((n_sub, k, d), np.float32)
    labels = np.zeros((len(x), 1), np.int32)  # an output (k-means++ seeding, no initial labels)
    for s in range(n_sub):
        cv2.setRNGSeed(_SEED + s)  # k-means++ seeding draws from OpenCV's RNG: seeded, reproducible
        _, _, centres = cv2.kmeans(np.ascontiguousarray(x[:, s * d:(s + 1) * d]), k, labels, criteria, 1,
                                   cv2.KMEANS_PP_CENTERS)
        book[s] = centres
    return book


def encode(desc: NDArray[np.floating], codebook: NDArray[np.float32]) -> NDArray[np.uint8]:
    """(M, D) descriptors -> (M, S) uint8 index of the nearest centroid per sub-vector."""
    x = np.asarray(desc, dtype=np.float32)
    n_sub, _, d = codebook.shape
    if x.ndim != 2 or x.shape[1] != n_sub * d:
        raise ValueError(f"descriptors must be (M, {n_sub * d}) for this codebook, got shape {x.shape}")
    codes = np.empty((len(x), n_sub), np.uint8)
    norms = np.einsum("skd,skd->sk", codebook, codebook)  # (S, K) squared centroid lengths
    for a in range(0, len(x), _CHUNK):
        chunk = x[a:a + _CHUNK]
        for s in range(n_sub):
            sub = chunk[:, s * d:(s + 1) * d]
            # argmin |x - c|^2 = argmin |c|^2 - 2 x.c
            codes[a:a + len(chunk), s] = np.argmin(norms[s][None, :] - 2.0 * (sub @ codebook[s].T), axis=1)
    return codes


def decode(codes: NDArray[np.integer], codebook: NDArray[np.float32]) -> NDArray[np.float32]:
    """(M, S) codes -> (M, D) float32 unit descriptors (zero rows stay zero)."""
    n_sub, _, d = codebook.shape
    c = np.asarray(codes)
    if c.ndim != 2 or c.shape[1] != n_sub:
        raise ValueError(f"codes must be (M, {n_sub}) for this codebook, got shape {c.shape}")
    out = codebook[np.arange(n_sub)[None, :], c.astype(np.intp)].reshape(len(c), n_sub * d)
    norm = np.linalg.norm(out, axis=1, keepdims=True)
    np.divide(out, norm, out=out, where=norm > 0)
    return out
