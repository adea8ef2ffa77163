"""Data types and interfaces of the model layer (numpy only; no torch, no onnxruntime)."""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from litevloc.base.errors import LiteVLocError


@dataclass(frozen=True, eq=False)
class Features:
    """Local features of one image, in the ORIGINAL image's pixels.

    keypoints: (N, 2) float32, x = u (column), y = v (row), pixel centres at integer
        coordinates (OpenCV convention), in the image passed to `extract`.
    descriptors: (N, D) float32, L2-normalised rows. ORB is the exception: (N, 32) uint8
        binary descriptors (Hamming distance).
    scores: (N,) float32 detection scores (higher is better; scale depends on the detector).
    image_size: (width, height) of the input image in pixels.
    """

    keypoints: NDArray[np.float32]
    descriptors: NDArray[np.float32]
    scores: NDArray[np.float32]
    image_size: tuple[int, int]

    def __post_init__(self) -> None:
        n = self.keypoints.shape[0]
        if self.keypoints.ndim != 2 or self.keypoints.shape[1] != 2:
            raise ValueError(f"keypoints must be (N, 2), got {self.keypoints.shape}")
        if self.descriptors.ndim != 2 or self.descriptors.shape[0] != n:
            raise ValueError(f"descriptors must be (N={n}, D), got {self.descriptors.shape}")
        if self.scores.shape != (n,):
            raise ValueError(f"scores must be ({n},), got {self.scores.shape}")

    def __len__(self) -> int:
        return int(self.keypoints.shape[0])


@dataclass(frozen=True, eq=False)
class Matches:
    """Correspondences between two feature sets: f0.keypoints[idx0[i]] <-> f1.keypoints[idx1[i]].

    idx0, idx1: (M,) int64 indices; scores: (M,) float32 confidence in [0, 1] (higher is better).
    """

    idx0: NDArray[np.int64]
    idx1: NDArray[np.int64]
    scores: NDArray[np.float32]

    def __post_init__(self) -> None:
        if not (self.idx0.shape == self.idx1.shape == self.scores.shape) or self.idx0.ndim != 1:
            raise ValueError(
                f"idx0, idx1, scores must be equal-length vectors, got {self.idx0.shape}, "
                f"{self.idx1.shape}, {self.scores.shape}"
            )

    def __len__(self) -> int:
        return int(self.idx0.shape[0])

    @staticmethod
    def empty() -> Matches:
        return Matches(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.float32))


class FeatureExtractor(Protocol):
    """image_rgb: HxWx3 uint8 RGB -> `Features` in that image's pixels."""

    name: str

    def extract(self, image_rgb: NDArray[np.uint8]) -> Features: ...


class Matcher(Protocol):
    name: str

    def match(self, f0: Features, f1: Features) -> Matches: ...


class PlaceRecognizer(Protocol):
    """image_rgb: HxWx3 uint8 RGB -> (dim,) float32 L2-normalised global descriptor."""

    name: str
    dim: int

    def describe(self, image_rgb: NDArray[np.uint8]) -> NDArray[np.float32]: ...


class ProviderState(Enum):
    """What the models' onnxruntime sessions run on, against what `models.providers` asks for
    (`models.ort.ProviderReport.state`; the service's diagnostics level follows it)."""

    NO_SESSIONS = "no_sessions"  # no ONNX session made (yet, or classical models only)
    AS_ASKED = "as_asked"  # every session runs on the first provider asked for
    FALLBACK = "fallback"  # a session runs on a later provider (e.g. tensorrt asked for, running on CPU)
    DISTRIBUTION_CLASH = "distribution_clash"  # two onnxruntime distributions installed (CPU over GPU build)


class OnnxRuntimeMissing(LiteVLocError, ImportError):
    """No onnxruntime distribution is installed (LiteVLoc's `cpu` and `gpu` extras each bring one)."""
