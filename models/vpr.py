"""Place recognition on onnxruntime: global descriptors from a fixed-size network input."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from litevloc.models.ort import make_session
from litevloc.models.preprocess import IMAGENET_MEAN, IMAGENET_STD, prepare_image
from numpy.typing import NDArray


class OnnxPlaceRecognizer:
    """ImageNet-normalised RGB at `size_hw` -> (dim,) float32 L2-normalised descriptor."""

    def __init__(
        self,
        path: Path,
        name: str,
        size_hw: tuple[int, int],
        providers: Sequence[str] = ("cpu",),
        intra_op_threads: int = 2,
    ) -> None:
        self.name = name
        self.size_hw = (int(size_hw[0]), int(size_hw[1]))
        self.session = make_session(path, providers, intra_op_threads)
        self.dim = int(self.session.get_outputs()[0].shape[-1])

    def describe(self, image_rgb: NDArray[np.uint8]) -> NDArray[np.float32]:
        x = prepare_image(image_rgb, self.size_hw, IMAGENET_MEAN, IMAGENET_STD)
        (d,) = self.session.run(None, {"image": x})
        v = d.reshape(-1).astype(np.float32)
        return (v / max(float(np.linalg.norm(v)), 1e-12)).astype(np.float32)
