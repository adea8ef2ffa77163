"""Updating a map from a session: the per-image memo that stops a frame's features and VPR
descriptor from being computed twice (once to localize it, once to observe it)."""

from __future__ import annotations

import numpy as np

from litevloc.pipelines.topomap.session import OncePerImage


def test_once_per_image_calls_the_model_once_per_frame() -> None:
    calls: list[int] = []

    def model(image: np.ndarray) -> float:
        calls.append(1)
        return float(image.sum())

    memo = OncePerImage(model)
    a = np.ones((4, 4), np.uint8)
    assert memo(a) == 16.0 and memo(a) == 16.0
    assert len(calls) == 1
    b = np.zeros((4, 4), np.uint8)  # the next frame: computed again, its own answer
    assert memo(b) == 0.0 and len(calls) == 2
    assert memo(a) == 16.0 and len(calls) == 3  # only the last image is remembered
