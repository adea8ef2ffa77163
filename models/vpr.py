"""Place recognition on onnxruntime: global descriptors from a fixed-size network input."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from litevloc.models.catalog import VPR_NORMALIZATION
from litevloc.models.ort import ProviderSetup, make_session
from litevloc.models.preprocess import prepare_image


class OnnxPlaceRecognizer:
    """RGB at `size_hw`, normalised as the network was trained (`VPR_NORMALIZATION[arch]`)
    -> (dim,) float32 L2-normalised descriptor. `arch`: effnet-gem | cosplace-r18."""

    def __init__(
        self,
        path: Path,
        name: str,
        arch: str,
        size_hw: tuple[int, int],
        providers: Sequence[str] | ProviderSetup = ("cpu",),
        intra_op_threads: int = 2,
    ) -> None:
        self.name = name
        self.mean, self.std = VPR_NORMALIZATION[arch]
        self.size_hw = (int(size_hw[0]), int(size_hw[1]))
        self.session = make_session(path, providers, intra_op_threads)
        self.dim = int(self.session.get_outputs()[0].shape[-1])

    def describe(self, image_rgb: NDArray[np.uint8]) -> NDArray[np.float32]:
        x = prepare_image(image_rgb, self.size_hw, self.mean, self.std)
        (d,) = self.session.run(None, {"image": x})
        v = d.reshape(-1).astype(np.float32)
        return np.asarray(v / max(float(np.linalg.norm(v)), 1e-12), dtype=np.float32)
