"""A bound on global localization's search: map keyframes within a radius of a given place
(an initial pose, e.g. RViz's "2D Pose Estimate" on /initialpose)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray


@dataclass(frozen=True, eq=False)
class SearchRegion:
    """`center_xy` (2,) metres in the map frame; `radius_m` metres (horizontal distance)."""

    center_xy: NDArray[np.float64]
    radius_m: float

    def __post_init__(self) -> None:
        c = np.asarray(self.center_xy, np.float64)
        if c.shape != (2,) or not np.all(np.isfinite(c)) or not (self.radius_m > 0 and np.isfinite(self.radius_m)):
            raise ValueError(f"search region needs a finite (2,) centre and radius > 0, got {c}, {self.radius_m}")


def nodes_within(order: NDArray[np.int64], positions: NDArray[np.floating], region: SearchRegion) -> NDArray[np.int64]:
    """The candidate nodes `order` (best first) whose keyframe position (`positions` (N, 3), map
    frame, metres) lies within `region` horizontally, in the same order."""
    order = np.asarray(order, np.int64)
    if order.size == 0:
        return order
    xy = np.asarray(positions, np.float64)[order, :2]
    d = np.linalg.norm(xy - np.asarray(region.center_xy, np.float64), axis=1)
    kept: NDArray[np.int64] = order[d <= region.radius_m]
    return kept
