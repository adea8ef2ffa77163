"""Classical baselines: SIFT / ORB (OpenCV) and descriptor matchers (NN + ratio, mutual NN)."""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

from litevloc.models.preprocess import resize_image, to_image_pixels
from litevloc.models.types import Features, Matches


class OpenCVExtractor:
    """SIFT (128-D float32, L2-normalised) or ORB (32-byte uint8 binary).

    The image is resized to `size_hw` by `resize_image` (shared with `prepare_image`),
    converted to grey, and keypoints are mapped back to the input image's pixels. At most
    `max_keypoints` keypoints, strongest first. Scores: OpenCV keypoint response.
    """

    def __init__(
        self, name: str, size_hw: tuple[int, int], max_keypoints: int = 1024, threads: int = 2
    ) -> None:
        if name not in ("sift", "orb"):
            raise ValueError(f"unknown OpenCV extractor {name!r}")
        self.name = name
        self.size_hw = size_hw
        self.max_keypoints = int(max_keypoints)
        cv2.setNumThreads(int(threads))
        factory = getattr(cv2, "SIFT_create" if name == "sift" else "ORB_create")
        self._det = factory(nfeatures=self.max_keypoints)

    def extract(self, image_rgb: NDArray[np.uint8]) -> Features:
        img = resize_image(image_rgb, self.size_hw)  # the same resize as `prepare_image`
        h, w = image_rgb.shape[:2]
        th, tw = self.size_hw
        grey = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
        kps, desc = self._det.detectAndCompute(grey, None)
        dim, dtype = (128, np.float32) if self.name == "sift" else (32, np.uint8)
        if desc is None or len(kps) == 0:
            return Features(
                np.zeros((0, 2), np.float32),
                np.zeros((0, dim), dtype),
                np.zeros(0, np.float32),
                (w, h),
            )
        order = np.argsort([-k.response for k in kps], kind="stable")[: self.max_keypoints]
        xy = np.array([kps[i].pt for i in order], np.float32).reshape(-1, 2)
        scores = np.array([kps[i].response for i in order], np.float32)
        desc = desc[order]
        if self.name == "sift":
            desc = desc.astype(np.float32)
            desc /= np.maximum(np.linalg.norm(desc, axis=1, keepdims=True), 1e-12)
        # OpenCV keypoints: pixel centres at integers, like ours
        xy = to_image_pixels(xy, (tw, th), (w, h))
        return Features(xy, desc, scores, (w, h))


def _distances(d0: NDArray[np.generic], d1: NDArray[np.generic]) -> NDArray[np.float32]:
    """(M, N) distances: Hamming for uint8 binary descriptors, Euclidean for float."""
    if d0.dtype == np.uint8:
        x = np.unpackbits(np.asarray(d0, dtype=np.uint8), axis=1).astype(np.float32)
        y = np.unpackbits(np.asarray(d1, dtype=np.uint8), axis=1).astype(np.float32)
        return (x @ (1 - y).T + (1 - x) @ y.T).astype(np.float32)
    sim = d0.astype(np.float32) @ d1.astype(np.float32).T
    sq0 = (d0.astype(np.float32) ** 2).sum(1)[:, None]
    sq1 = (d1.astype(np.float32) ** 2).sum(1)[None]
    return np.asarray(np.sqrt(np.maximum(sq0 + sq1 - 2 * sim, 0)), dtype=np.float32)


def _check(f0: Features, f1: Features) -> None:
    if (
        f0.descriptors.dtype != f1.descriptors.dtype
        or f0.descriptors.shape[1] != f1.descriptors.shape[1]
    ):
        raise ValueError(
            f"descriptor mismatch: {f0.descriptors.dtype}x{f0.descriptors.shape[1]} vs "
            f"{f1.descriptors.dtype}x{f1.descriptors.shape[1]}"
        )


def _score(dist: NDArray[np.float32], binary: bool) -> NDArray[np.float32]:
    """Distance -> confidence in [0, 1]: 1 - d/d_max (d_max = 256 bits or 2 for unit vectors)."""
    dmax = 256.0 if binary else 2.0
    return np.asarray(np.clip(1.0 - dist / dmax, 0.0, 1.0), dtype=np.float32)


class RatioMatcher:
    """Nearest neighbour with Lowe's ratio test (d1 < ratio * d2), one-directional 0 -> 1."""

    def __init__(self, ratio: float = 0.8) -> None:
        self.name = "nn-ratio"
        self.ratio = float(ratio)

    def match(self, f0: Features, f1: Features) -> Matches:
        _check(f0, f1)
        if len(f0) == 0 or len(f1) < 2:
            return Matches.empty()
        d = _distances(f0.descriptors, f1.descriptors)
        part = np.argpartition(d, 1, axis=1)[:, :2]
        rows = np.arange(d.shape[0])
        d_a, d_b = d[rows, part[:, 0]], d[rows, part[:, 1]]
        best = np.where(d_a <= d_b, part[:, 0], part[:, 1])
        d1, d2 = np.minimum(d_a, d_b), np.maximum(d_a, d_b)
        ok = d1 < self.ratio * d2
        idx0 = rows[ok].astype(np.int64)
        return Matches(
            idx0, best[ok].astype(np.int64), _score(d1[ok], f0.descriptors.dtype == np.uint8)
        )


class MutualNNMatcher:
    """Mutual nearest neighbours (optionally also `max_distance`); fast mode for ALIKED."""

    def __init__(self, max_distance: float | None = None) -> None:
        self.name = "mnn"
        self.max_distance = max_distance

    def match(self, f0: Features, f1: Features) -> Matches:
        _check(f0, f1)
        if len(f0) == 0 or len(f1) == 0:
            return Matches.empty()
        d = _distances(f0.descriptors, f1.descriptors)
        nn01 = d.argmin(1)
        nn10 = d.argmin(0)
        idx0 = np.nonzero(nn10[nn01] == np.arange(d.shape[0]))[0]
        idx1 = nn01[idx0]
        dist = d[idx0, idx1]
        if self.max_distance is not None:
            keep = dist <= self.max_distance
            idx0, idx1, dist = idx0[keep], idx1[keep], dist[keep]
        return Matches(
            idx0.astype(np.int64),
            idx1.astype(np.int64),
            _score(dist, f0.descriptors.dtype == np.uint8),
        )
