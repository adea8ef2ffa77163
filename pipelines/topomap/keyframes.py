"""Keyframe selection: motion pre-filter, then greedy coverage maximisation.

1. Pre-filter (in time order): keep a frame when it moved >= `min_translation_m` or
   turned >= `min_rotation_deg` since the last kept frame.
2. Greedy information maximisation: every candidate "covers" a set of (ground-plane
   cell, viewing-direction bin) pairs — the cells hit by its depth points (inside a
   height band), each with the direction from the camera to that cell quantised into
   `heading_bins` sectors (1 bin = the published plain 2D coverage; more bins also value
   seeing a place from a new side, which is what a query from that side needs). Each
   round picks the candidate adding the most uncovered pairs (ties: earliest frame).
   Stop at the budget, when the coverage of the union reaches `coverage`, or when the
   best gain is below `min_gain`.

No randomness: the same input and parameters always select the same keyframes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from litevloc.pipelines.geometry import rotation_angle

_OFF = 1 << 20


@dataclass(frozen=True)
class KeyframeParams:
    """Keyframe selection parameters (metres, degrees)."""

    min_translation_m: float = 0.1
    min_rotation_deg: float = 3.0
    budget: int = 40
    coverage: float = 0.95
    cell_m: float = 0.25
    heading_bins: int = 8
    height_band_m: tuple[float, float] = (-2.0, 1.0)  # relative to the median camera height, along `up`
    max_depth_m: float = 5.0
    pixel_stride: int = 8
    min_gain: int = 1

    def __post_init__(self) -> None:
        if self.min_translation_m < 0 or self.min_rotation_deg < 0:
            raise ValueError("motion thresholds must be >= 0")
        if self.budget < 1:
            raise ValueError(f"budget must be >= 1, got {self.budget}")
        if not (0 < self.coverage <= 1):
            raise ValueError(f"coverage must be in (0, 1], got {self.coverage}")
        if self.cell_m <= 0 or self.heading_bins < 1 or self.pixel_stride < 1 or self.max_depth_m <= 0:
            raise ValueError("cell_m, max_depth_m must be > 0; heading_bins, pixel_stride >= 1")
        if self.height_band_m[0] >= self.height_band_m[1]:
            raise ValueError(f"height_band_m must be (low, high) with low < high, got {self.height_band_m}")


def motion_prefilter(T_map_camera: NDArray[np.float64], params: KeyframeParams) -> list[int]:
    """Indices (into the (N,4,4) pose array) of frames passing the motion pre-filter."""
    if len(T_map_camera) == 0:
        return []
    kept = [0]
    min_rot = np.radians(params.min_rotation_deg)
    for i in range(1, len(T_map_camera)):
        last = T_map_camera[kept[-1]]
        dt = float(np.linalg.norm(T_map_camera[i][:3, 3] - last[:3, 3]))
        dr = rotation_angle(last[:3, :3].T @ T_map_camera[i][:3, :3])
        if dt >= params.min_translation_m or dr >= min_rot:
            kept.append(i)
    return kept


def plane_axes(up: NDArray[np.floating]) -> NDArray[np.float64]:
    """(2, 3) orthonormal axes spanning the plane orthogonal to `up` (right-handed with up)."""
    u = np.asarray(up, dtype=np.float64)
    u = u / np.linalg.norm(u)
    e = np.eye(3)[int(np.argmin(np.abs(u)))]
    a = np.cross(e, u)
    a /= np.linalg.norm(a)
    b = np.cross(u, a)
    return np.stack([a, b])


def coverage_keys(
    points_map: NDArray[np.float64], camera_map: NDArray[np.float64], up: NDArray[np.float64],
    ref_height: float, params: KeyframeParams,
) -> NDArray[np.int64]:
    """Unique int64 keys of the (cell, heading bin) pairs covered by one frame.

    Args:
        points_map: (N, 3) depth points of the frame in the map frame (already range-limited).
        camera_map: (3,) camera centre in the map frame.
        up: (3,) unit up vector; ref_height: median camera height along `up`.
    """
    if len(points_map) == 0:
        return np.zeros(0, dtype=np.int64)
    axes = plane_axes(up)
    h = points_map @ up - ref_height
    lo, hi = params.height_band_m
    p = points_map[(h >= lo) & (h <= hi)]
    if len(p) == 0:
        return np.zeros(0, dtype=np.int64)
    xy = p @ axes.T
    cxy = camera_map @ axes.T
    ij = np.floor(xy / params.cell_m).astype(np.int64)
    centres = (ij + 0.5) * params.cell_m
    ang = np.arctan2(centres[:, 1] - cxy[1], centres[:, 0] - cxy[0])
    b = np.floor((ang + np.pi) / (2 * np.pi) * params.heading_bins).astype(np.int64) % params.heading_bins
    keys = ((ij[:, 0] + _OFF) * (2 * _OFF) + (ij[:, 1] + _OFF)) * 64 + b
    return np.unique(keys)


def greedy_select(cover: list[NDArray[np.int64]], params: KeyframeParams) -> tuple[list[int], list[float]]:
    """Greedy max-coverage. Returns (selected positions into `cover`, coverage after each pick)."""
    universe = np.unique(np.concatenate(cover)) if cover else np.zeros(0, dtype=np.int64)
    total = len(universe)
    selected: list[int] = []
    history: list[float] = []
    if total == 0:
        return ([0] if cover else []), ([1.0] if cover else [])
    covered = np.zeros(0, dtype=np.int64)
    remaining = set(range(len(cover)))
    while remaining and len(selected) < params.budget:
        best, best_gain = -1, -1
        for c in sorted(remaining):
            gain = int(len(cover[c]) - np.count_nonzero(np.isin(cover[c], covered, assume_unique=True)))
            if gain > best_gain:
                best, best_gain = c, gain
        if best_gain < params.min_gain:
            break
        selected.append(best)
        remaining.discard(best)
        covered = np.union1d(covered, cover[best])
        history.append(len(covered) / total)
        if history[-1] >= params.coverage:
            break
    return selected, history
