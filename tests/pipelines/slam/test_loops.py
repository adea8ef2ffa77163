"""Loop search's cost bound: a candidate the chain places too far for the chain gate is never matched."""

from __future__ import annotations

import dataclasses

import numpy as np
from numpy.typing import NDArray

from litevloc.base.geometry import make_T
from litevloc.config import load_config
from litevloc.pipelines.slam.loops import LoopCounts, LoopSearch, loop_closures
from litevloc.pipelines.slam.types import Keyframe
from litevloc.pipelines.topomap.types import FeatureSet, NodeFeatures

K = np.array([[200.0, 0.0, 160.0], [0.0, 200.0, 120.0], [0.0, 0.0, 1.0]])


def _keyframe(i: int, xy: tuple[float, float], path_m: float, chain: int = 0) -> Keyframe:
    feats = NodeFeatures(np.zeros((0, 2), np.float32), np.zeros((0, 8), np.float32), np.zeros(0, np.float32),
                         (320, 240), np.zeros(0, np.float32))
    return Keyframe(i, i, i, K, (320, 240), feats, np.zeros((0, 3)), np.ones(4, np.float32) / 2, b"",
                    np.zeros((0, 3), np.float32), None, make_T(np.eye(3), np.array([xy[0], xy[1], 0.0])), chain,
                    path_m, 1e-6 * path_m)


class _CountingMatcher:
    """The loop matcher's double: finds nothing, counts the pairs it was asked to match."""

    def __init__(self) -> None:
        self.pairs = 0

    def __call__(self, a: FeatureSet, b: FeatureSet) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        self.pairs += 1
        return np.zeros(0, np.int64), np.zeros(0, np.int64)


def _search(kfs: list[Keyframe], q: Keyframe, pregate: bool) -> tuple[LoopCounts, int]:
    cfg = load_config("default")
    params = dataclasses.replace(cfg.slam.loops, max_verifications=2)
    search = LoopSearch(params)
    for kf in kfs:
        search.add(kf.id, kf.vpr)
    counts, match = LoopCounts(), _CountingMatcher()
    loop_closures(q, kfs, search, match, cfg.localization, params, counts,
                  cfg.slam.graph if pregate else None)
    return counts, match.pairs


def test_a_repetition_down_the_corridor_is_not_matched() -> None:
    # a straight corridor whose every place looks alike: keyframe 30, 15 m along, gets the first
    # keyframes as candidates, 14-15 m back along a 15 m chain (the gate allows ~1.6 m + a 5 m loop)
    kfs = [_keyframe(i, (0.5 * i, 0.0), 0.5 * i) for i in range(31)]
    counts, pairs = _search(kfs, kfs[30], pregate=True)
    assert counts.candidates == 3 and counts.pregated == 3 and counts.tried == 0 and pairs == 0
    counts, pairs = _search(kfs, kfs[30], pregate=False)
    assert counts.pregated == 0 and counts.tried == 2 and pairs == 2


def test_a_revisit_and_another_chain_are_matched() -> None:
    # the chain comes back to its start after a 40 m lap: its drift bound covers the revisit
    kfs = [_keyframe(i, (0.5 * i, 0.0), 0.5 * i) for i in range(30)]
    kfs.append(_keyframe(30, (0.2, 0.1), 40.0))
    counts, pairs = _search(kfs, kfs[30], pregate=True)
    assert counts.pregated == 0 and counts.tried == 2 and pairs == 2
    # a keyframe on another chain: the chain says nothing about where it is
    kfs[30] = _keyframe(30, (15.0, 0.0), 0.0, chain=1)
    counts, pairs = _search(kfs, kfs[30], pregate=True)
    assert counts.pregated == 0 and counts.tried == 2 and pairs == 2
