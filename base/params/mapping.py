"""Parameters of map building: keyframe selection, occupancy grid, covisibility and
connectivity graphs, and the whole mapping section (config `mapping`; the algorithms are
`pipelines.topomap.keyframes`, `.occupancy`, `.graphs` and `.build`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from litevloc.base.params.localization import DepthLookupParams, PnpParams
from litevloc.base.params.map_maintenance import DiffParams, MergeParams, UpdateParams


@dataclass(frozen=True)
class KeyframeParams:
    """Keyframe selection parameters (metres, degrees)."""

    # pre-filter: a frame is a candidate when it moved this far since the last candidate (m) ...
    min_translation_m: float = 0.3
    # ... or turned this far (degrees)
    min_rotation_deg: float = 12.0
    # explicit cap on the keyframe count (null: the coverage target decides)
    budget: int | None = None
    # keyframes are added until they cover this share of what the candidates cover
    coverage: float = 0.95
    # ground-plane cell of the coverage count (m)
    cell_m: float = 0.5
    # viewing-direction sectors per cell (1 = plain 2D coverage)
    heading_bins: int = 8
    # depth points counted for coverage lie in this band around the median camera height, along `up` (m)
    height_band_m: tuple[float, float] = (-0.4, 2.5)
    # depth points farther than this (along the optical axis) are not counted for coverage (m)
    max_depth_m: float = 6.0
    # every this many pixels of the depth image are counted (pixels)
    pixel_stride: int = 8
    # the greedy selection stops when the best candidate adds fewer (cell, direction) pairs
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

    # grid cell size (m)
    resolution_m: float = 0.1
    # depth points in this band around the median camera height are obstacles (m, along `up`)
    obstacle_band_m: tuple[float, float] = (-0.35, 1.5)
    # obstacle points that make a cell occupied
    min_points: int = 3
    # free border around the observed area (m)
    margin_m: float = 0.5

    def __post_init__(self) -> None:
        if self.resolution_m <= 0 or self.min_points < 1 or self.margin_m < 0:
            raise ValueError("resolution_m > 0, min_points >= 1, margin_m >= 0 required")
        if self.obstacle_band_m[0] >= self.obstacle_band_m[1]:
            raise ValueError(f"obstacle_band_m must be (low, high) with low < high, got {self.obstacle_band_m}")


@dataclass(frozen=True)
class CovisibilityParams:
    """Covisibility verification parameters."""

    # keyframe pairs farther apart are not verified (m)
    max_distance_m: float = 5.0
    # keyframe pairs whose optical axes differ more are not verified (degrees)
    max_angle_deg: float = 90.0
    # PnP inliers that make an edge
    min_inliers: int = 30
    # edge weight = min(inliers / this, 1)
    weight_saturation: int = 200
    # pair matching: "guided" by projecting with the mapping poses (~1 ms), "model" runs the matcher (~250 ms)
    matching: Literal["guided", "model"] = "guided"
    # guided matching: search radius around the projected point (pixels; absorbs the mapping poses' error)
    guided_radius_px: float = 40.0
    # guided matching: smallest descriptor similarity of a pair (cosine)
    guided_min_similarity: float = 0.6
    # guided matching: each pair must also be mutual nearest neighbours over all keypoints
    guided_global_mutual: bool = False
    # PnP of one keyframe's depth-lifted keypoints into the other
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

    # keyframes this close on the ground plane are connected when the straight way is free (m)
    max_line_of_sight_m: float = 3.0
    # line-of-sight edges kept per keyframe, nearest first
    max_line_of_sight_neighbours: int = 6

    def __post_init__(self) -> None:
        if self.max_line_of_sight_m < 0:
            raise ValueError("max_line_of_sight_m must be >= 0")
        if self.max_line_of_sight_neighbours < 1:
            raise ValueError("max_line_of_sight_neighbours must be >= 1")


@dataclass(frozen=True)
class MappingParams:
    """All map-building parameters (config `mapping`)."""

    # unit up vector of the map frame (against gravity)
    up: tuple[float, float, float] = (0.0, 0.0, 1.0)
    # matcher of covisibility.matching: model (mnn = mutual nearest neighbours, ~100x faster than LightGlue)
    covisibility_matcher: str = "mnn"
    # which frames become keyframes
    keyframes: KeyframeParams = field(default_factory=KeyframeParams)
    # the occupancy grid (for planning)
    occupancy: OccupancyParams = field(default_factory=OccupancyParams)
    # the covisibility graph (for localization)
    covisibility: CovisibilityParams = field(default_factory=CovisibilityParams)
    # the connectivity graph (for planning)
    connectivity: ConnectivityParams = field(default_factory=ConnectivityParams)
    # validity gates of the mapping depth at keypoints
    depth: DepthLookupParams = field(default_factory=DepthLookupParams)
    # JPEG quality of keyframe images encoded from raw colour (a source's own JPEGs are kept as they are)
    jpeg_quality: int = 75
    # keep only the strongest N keypoints of each keyframe in the map (0 = all)
    stored_keypoints: int = 0
    # bytes per stored local descriptor: product-quantiser sub-codes (must divide D), or 0 = int8 codes
    descriptor_bytes: int = 32
    # `litevloc map merge`: joining sessions mapped in different frames
    merge: MergeParams = field(default_factory=MergeParams)
    # `litevloc map update`: refreshing a map from a new session
    update: UpdateParams = field(default_factory=UpdateParams)
    # `litevloc map diff`: comparing two versions of a map
    diff: DiffParams = field(default_factory=DiffParams)

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
