"""Map quality on a posed query pass (`bench/mapping.py`): VPR recall against the map's keyframes."""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from litevloc.base.geometry import rotation_angle
from litevloc.pipelines.topomap.types import TopoMap


@dataclass(frozen=True)
class VprRecall:
    """Shares of query frames whose true place a retrieved keyframe matches."""

    queries: int
    recall_at_1: float
    recall_at_5: float
    oracle: float  # some keyframe of the map is within the thresholds at all


def vpr_recall(
    m: TopoMap, describe: Callable[[NDArray[np.uint8]], NDArray[np.float32]],
    queries: Iterable[tuple[NDArray[np.uint8], NDArray[np.float64]]], max_m: float = 0.5, max_deg: float = 30.0,
) -> VprRecall:
    """Recall@1/@5 of `describe` against the map's VPR descriptors over (RGB image, true
    T_map_camera) queries; a retrieved keyframe is correct within `max_m` and `max_deg`."""
    hits1 = hits5 = oracle = n = 0
    for image, T in queries:
        n += 1
        d = np.linalg.norm(m.positions - T[:3, 3], axis=1)
        ang = np.array([np.degrees(rotation_angle(Tn[:3, :3].T @ T[:3, :3])) for Tn in m.T_map_camera])
        good = (d <= max_m) & (ang <= max_deg)
        order = np.argsort(-(m.vpr @ describe(image)))
        hits1 += bool(good[order[0]])
        hits5 += bool(good[order[:5]].any())
        oracle += bool(good.any())
    if n == 0:
        raise ValueError("no query frame with a ground-truth pose")
    return VprRecall(n, hits1 / n, hits5 / n, oracle / n)
