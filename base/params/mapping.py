"""Parameters of map building: keyframe selection, occupancy grid, covisibility and
connectivity graphs, and the whole mapping section.

Re-exported by `pipelines.topomap.keyframes`, `.occupancy`, `.graphs` and `.build` under
their old names (the algorithms live there).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from litevloc.base.params.localization import DepthLookupParams, PnpParams


@dataclass(frozen=True)
class KeyframeParams:
    """Keyframe selection parameters (metres, degrees)."""

    min_translation_m: float = 0.1
    min_rotation_deg: float = 3.0
    budget: int | None = None  # explicit cap on the keyframe count (None: coverage decides)
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
        if self.budget is not None and self.budget < 1:
            raise ValueError(f"budget must be >= 1, got {self.budget}")
        if not (0 < self.coverage <= 1):
            raise ValueError(f"coverage must be in (0, 1], got {self.coverage}")
        if self.cell_m <= 0 or self.heading_bins < 1 or self.pixel_stride < 1 or self.max_depth_m <= 0:
            raise ValueError("cell_m, max_depth_m must be > 0; heading_bins, pixel_stride >= 1")
        if self.height_band_m[0] >= self.height_band_m[1]:
            raise ValueError(f"height_band_m must be (low, high) with low < high, got {self.height_band_m}")


@dataclass(frozen=True)
class OccupancyParams:
    """Occupancy grid parameters (metres)."""

    resolution_m: float = 0.1
    obstacle_band_m: tuple[float, float] = (-1.0, 0.5)  # relative to the median camera height
    min_points: int = 3
    margin_m: float = 0.5

    def __post_init__(self) -> None:
        if self.resolution_m <= 0 or self.min_points < 1 or self.margin_m < 0:
            raise ValueError("resolution_m > 0, min_points >= 1, margin_m >= 0 required")
        if self.obstacle_band_m[0] >= self.obstacle_band_m[1]:
            raise ValueError(f"obstacle_band_m must be (low, high) with low < high, got {self.obstacle_band_m}")


@dataclass(frozen=True)
class CovisibilityParams:
    """Covisibility verification parameters."""

    max_distance_m: float = 3.5
    max_angle_deg: float = 90.0
    min_inliers: int = 30
    weight_saturation: int = 200
    # How a candidate pair is matched before PnP: "guided" projects node i's depth-lifted
    # keypoints into node j with the two mapping poses and pairs each with the most similar
    # keypoint within guided_radius_px (mutual nearest neighbours over all keypoints too, so
    # the poses only filter matches they did not choose; ~1 ms per pair); "model" runs the
    # configured matcher (LightGlue: ~250 ms per pair on 2 CPUs, 661 of the 960 s that the
    # 268-keyframe floor map took to build).
    # The radius absorbs the mapping poses' error: on the 7-Scenes mapping pass the ground-truth
    # relative poses of keyframe pairs are off by up to ~2.5 deg (25 px at f = 585) and colour and
    # depth are not registered; 8 px kept 11 of the 31 edges the matcher found (frames 0:200:4,
    # ORB), 40 px 27 of 31 (70 of 84 on frames 200:500:6), with no edge the matcher did not find.
    matching: Literal["guided", "model"] = "guided"
    guided_radius_px: float = 40.0
    guided_min_similarity: float = 0.6
    # Also require each pair to be the mutual nearest neighbour over all keypoints of both
    # images. Off: the mapping poses are trusted (no wrong pose to confirm itself), and on
    # repetitive walls the global test drops most true matches (loop world: 407 edges with it
    # against 2432 from LightGlue).
    guided_global_mutual: bool = False
    pnp: PnpParams = field(
        default_factory=lambda: PnpParams(min_inliers=10, min_inlier_ratio=0.0, max_median_reprojection_px=3.0)
    )

    def __post_init__(self) -> None:
        if self.max_distance_m <= 0 or not (0 < self.max_angle_deg <= 180):
            raise ValueError("max_distance_m > 0 and max_angle_deg in (0, 180] required")
        if self.min_inliers < 4 or self.weight_saturation < 1:
            raise ValueError("min_inliers >= 4 and weight_saturation >= 1 required")
        if self.matching not in ("guided", "model"):
            raise ValueError(f"unknown covisibility matching {self.matching!r} (guided | model)")
        if self.guided_radius_px <= 0 or not (-1 <= self.guided_min_similarity <= 1):
            raise ValueError("need guided_radius_px > 0 and guided_min_similarity in [-1, 1]")


@dataclass(frozen=True)
class ConnectivityParams:
    """Connectivity (reachability) parameters."""

    max_line_of_sight_m: float = 2.0
    max_line_of_sight_neighbours: int = 6

    def __post_init__(self) -> None:
        if self.max_line_of_sight_m < 0:
            raise ValueError("max_line_of_sight_m must be >= 0")
        if self.max_line_of_sight_neighbours < 1:
            raise ValueError("max_line_of_sight_neighbours must be >= 1")


@dataclass(frozen=True)
class MappingParams:
    """All map-building parameters. `up` is the unit up vector of the map frame.

    `covisibility_matcher` names the matcher the caller should inject for covisibility
    verification (mutual-NN by default: PnP-RANSAC verification makes the cheap matcher
    good enough, and it is ~100x faster than LightGlue over all keyframe pairs).
    """

    up: tuple[float, float, float] = (0.0, 0.0, 1.0)
    covisibility_matcher: str = "mnn"
    keyframes: KeyframeParams = field(default_factory=KeyframeParams)
    occupancy: OccupancyParams = field(default_factory=OccupancyParams)
    covisibility: CovisibilityParams = field(default_factory=CovisibilityParams)
    connectivity: ConnectivityParams = field(default_factory=ConnectivityParams)
    depth: DepthLookupParams = field(default_factory=DepthLookupParams)
    # JPEG quality of keyframe images encoded from raw colour (a source's own JPEG bytes, e.g. a
    # recording's, are stored as they are). They are for people (live view, map diff) and
    # `bench reloc`, not localization: 75 stores them in 55 % of the bytes of 90 (`loop`: 2.26
    # vs 4.14 MB for 311 keyframes)
    jpeg_quality: int = 75
    # keep only the strongest N keypoints of each keyframe in the map (0 = all the extractor
    # gives): local features are most of a map's bytes (#15); queries still use all theirs
    stored_keypoints: int = 0
    # bytes per stored float local descriptor: a product quantiser with this many 8-bit
    # sub-codes and a codebook trained on the map (`pipelines/topomap/descriptor_codec.py`;
    # must divide the descriptor dimension; 32 for 128-d ALIKED: 4x smaller than int8), or
    # 0 (or >= D) = int8 codes + one float32 scale per descriptor (map format 2, D + 4 bytes)
    descriptor_bytes: int = 32

    def __post_init__(self) -> None:
        if not 0 <= self.descriptor_bytes <= 4096:
            raise ValueError(f"descriptor_bytes must be in [0, 4096] (0 = int8 codes), got {self.descriptor_bytes}")
        if self.stored_keypoints < 0:
            raise ValueError(f"stored_keypoints must be >= 0 (0 = all), got {self.stored_keypoints}")
        n = float(np.linalg.norm(self.up))
        if not np.isfinite(n) or n < 1e-6:
            raise ValueError(f"up must be a non-zero vector, got {self.up}")
        if not (1 <= self.jpeg_quality <= 100):
            raise ValueError("jpeg_quality must be in [1, 100]")
