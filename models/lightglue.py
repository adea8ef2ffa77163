"""LightGlue (for ALIKED) on onnxruntime (export: `litevloc.models.export.lightglue`)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from litevloc.models.ort import make_session
from litevloc.models.types import Features, Matches


def normalize_keypoints(
    kpts: NDArray[np.float32], image_size: tuple[int, int]
) -> NDArray[np.float32]:
    """(N, 2) pixels of an image of (width, height) -> LightGlue's frame: centred, / max side/2."""
    w, h = image_size
    shift = np.array([w / 2.0, h / 2.0], np.float32)
    return ((kpts - shift) / np.float32(max(w, h) / 2.0)).astype(np.float32)


class LightGlueOnnx:
    """Full-depth LightGlue (9 layers, no early stopping / pruning) with dynamic keypoint counts.

    Matches are the mutual best entries of the assignment with score > `threshold` (the
    reference default 0.1). Works on ALIKED features (128-D descriptors: n16; t16's 64-D
    descriptors are rejected with a clear error since LightGlue was trained on n16).
    """

    def __init__(
        self,
        path: Path,
        threshold: float = 0.1,
        providers: Sequence[str] = ("cpu",),
        intra_op_threads: int = 2,
    ) -> None:
        self.name = "lightglue"
        self.threshold = float(threshold)
        self.session = make_session(path, providers, intra_op_threads)
        self.input_dim = int(self.session.get_inputs()[2].shape[-1])

    def match(self, f0: Features, f1: Features) -> Matches:
        for f in (f0, f1):
            if f.descriptors.dtype != np.float32 or f.descriptors.shape[1] != self.input_dim:
                raise ValueError(
                    f"LightGlue needs float32 {self.input_dim}-D descriptors (ALIKED), "
                    f"got {f.descriptors.dtype} {f.descriptors.shape[1]}-D"
                )
        if len(f0) == 0 or len(f1) == 0:
            return Matches.empty()
        feeds = {
            "kpts0": normalize_keypoints(f0.keypoints, f0.image_size)[None],
            "kpts1": normalize_keypoints(f1.keypoints, f1.image_size)[None],
            "desc0": np.ascontiguousarray(f0.descriptors[None]),
            "desc1": np.ascontiguousarray(f1.descriptors[None]),
        }
        m0, s0 = self.session.run(None, feeds)
        m0, s0 = m0[0], s0[0]
        valid = (m0 >= 0) & (s0 > self.threshold)
        idx0 = np.nonzero(valid)[0].astype(np.int64)
        return Matches(idx0, m0[valid].astype(np.int64), s0[valid].astype(np.float32))
