from __future__ import annotations

import numpy as np

from litevloc.models.types import Features, Matches
from litevloc.runtime.vloc_models import ModelBundle


class EchoMatcher:
    """Matches keypoint i of f0 with keypoint i of f1 (both already truncated)."""

    name = "echo"

    def match(self, f0: Features, f1: Features) -> Matches:
        n = min(len(f0.keypoints), len(f1.keypoints))
        idx = np.arange(n, dtype=np.int64)
        return Matches(idx, idx, np.ones(n, np.float32))


def feats(scores: list[float]) -> Features:
    n = len(scores)
    kp = np.stack([np.arange(n), np.arange(n)], 1).astype(np.float32)
    return Features(kp, np.eye(n, 8, dtype=np.float32), np.array(scores, np.float32), (64, 48))


def test_top_n_matching_returns_indices_into_the_full_sets() -> None:
    b = ModelBundle(extractor=None, matcher=EchoMatcher(), vpr=None, max_keypoints=2)  # type: ignore[arg-type]
    i0, i1 = b.match(feats([0.1, 0.9, 0.5, 0.8]), feats([0.7, 0.2, 0.95]))
    assert i0.tolist() == [1, 3] and i1.tolist() == [0, 2]  # the two best of each, original order
    b.max_keypoints = 0
    i0, _ = b.match(feats([0.1, 0.9, 0.5]), feats([0.7, 0.2, 0.95]))
    assert i0.tolist() == [0, 1, 2]
