"""ALIKED feature extractor on onnxruntime (export: `litevloc.models.export.aliked`)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from litevloc.models.ort import ProviderSetup, make_session
from litevloc.models.preprocess import prepare_image, to_image_pixels
from litevloc.models.types import Features


class AlikedOnnx:
    """ALIKED at a fixed network input size (h, w) returning the exported top-k keypoints.

    `extract` resizes the image with `prepare_image` (RGB in [0, 1], no mean/std), runs the
    network and maps keypoints back to the input image's pixels (`to_image_pixels`).
    Descriptors (K, 64 for t16 / 128 for n16) float32 L2-normalised; scores (K,) in [0, 1].
    """

    def __init__(
        self,
        path: Path,
        name: str,
        size_hw: tuple[int, int],
        providers: Sequence[str] | ProviderSetup = ("cpu",),
        intra_op_threads: int = 2,
    ) -> None:
        self.name = name
        self.size_hw = (int(size_hw[0]), int(size_hw[1]))
        self.session = make_session(path, providers, intra_op_threads)
        shape = self.session.get_inputs()[0].shape
        if list(shape[2:]) != list(self.size_hw):
            raise ValueError(f"{path}: network input is {shape}, expected (1, 3, {self.size_hw})")

    def extract(self, image_rgb: NDArray[np.uint8]) -> Features:
        h, w = image_rgb.shape[:2]
        x = prepare_image(image_rgb, self.size_hw)
        kpts, desc, scores = self.session.run(None, {"image": x})
        kpts = to_image_pixels(kpts, (self.size_hw[1], self.size_hw[0]), (w, h))
        return Features(
            kpts.astype(np.float32), desc.astype(np.float32), scores.astype(np.float32), (w, h)
        )
