"""Parameters of map building: keyframe selection, occupancy grid, covisibility and
connectivity graphs, and the whole mapping section (config `mapping`; the algorithms are
`pipelines.topomap.keyframes`, `.occupancy`, `.graphs` and `.build`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from litevloc.base.params.localization import DepthLookupParams, PnpParams
from litevloc.base.params.map_maintenance import DiffParams, MergeParams, UpdateParams
from litevloc.base.settings import Settings, section, setting


@dataclass(frozen=True)
class KeyframeParams(Settings):
    """Keyframe selection parameters (metres, degrees)."""

    min_translation_m: float = setting(
        0.3, "pre-filter: a frame is a keyframe candidate when it moved this far since the last candidate", low=0,
        unit="m")
    min_rotation_deg: float = setting(
        12.0, "pre-filter: a frame is a keyframe candidate when it turned this far since the last candidate",
        unit="deg", low=0)
    budget: int | None = setting(None, "explicit cap on the keyframe count (null: the coverage target decides)", low=1)
    coverage: float = setting(
        0.95, "keyframes are added until they cover this share of what the candidates cover", low=0, low_open=True,
        high=1)
    cell_m: float = setting(0.5, "ground-plane cell of the coverage count", unit="m", low=0, low_open=True)
    heading_bins: int = setting(8, "viewing-direction sectors per cell (1 = plain 2D coverage)", low=1)
    height_band_m: tuple[float, float] = setting(
        (-0.4, 2.5),
        "depth points counted for coverage lie in this band around the median camera height, along `up` (low < high)",
        unit="m", low=-math.inf)
    max_depth_m: float = setting(
        6.0, "depth points farther than this (along the optical axis) are not counted for coverage", unit="m", low=0,
        low_open=True)
    pixel_stride: int = setting(
        8, "every this many pixels of the depth image are counted for coverage", unit="px", low=1)
    min_gain: int = setting(
        1, "the greedy selection stops when the best candidate adds fewer (cell, direction) pairs", low=-math.inf)

    def check_relations(self) -> None:
        if self.height_band_m[0] >= self.height_band_m[1]:
            raise ValueError(f"height_band_m must be (low, high) with low < high, got {self.height_band_m}")


@dataclass(frozen=True)
class OccupancyParams(Settings):
    """Occupancy grid parameters (metres)."""

    resolution_m: float = setting(0.1, "occupancy grid cell size", unit="m", low=0, low_open=True)
    obstacle_band_m: tuple[float, float] = setting(
        (-0.35, 1.5), "depth points in this band around the median camera height are obstacles (along `up`)", unit="m",
        low=-math.inf)
    min_points: int = setting(3, "obstacle points that make an occupancy cell occupied", low=1)
    margin_m: float = setting(0.5, "free border of the occupancy grid around the observed area", unit="m", low=0)

    def check_relations(self) -> None:
        if self.obstacle_band_m[0] >= self.obstacle_band_m[1]:
            raise ValueError(f"obstacle_band_m must be (low, high) with low < high, got {self.obstacle_band_m}")


@dataclass(frozen=True)
class CovisibilityParams(Settings):
    """Covisibility verification parameters."""

    max_distance_m: float = setting(
        5.0, "keyframe pairs farther apart than this are not verified for covisibility", unit="m", low=0, low_open=True)
    max_angle_deg: float = setting(
        90.0, "keyframe pairs whose optical axes differ more than this are not verified for covisibility", unit="deg",
        low=0, low_open=True, high=180)
    min_inliers: int = setting(30, "PnP inliers that make a covisibility edge", low=4)
    weight_saturation: int = setting(200, "covisibility edge weight = min(inliers / this, 1)", low=1)
    matching: Literal["guided", "model"] = setting(
        "guided", 'pair matching: "guided" by projecting with the mapping poses (~1 ms), "model" runs the matcher '
        "(~250 ms)")
    guided_radius_px: float = setting(
        40.0, "guided matching: search radius around the projected point (absorbs the mapping poses' error)", unit="px",
        low=0, low_open=True)
    guided_min_similarity: float = setting(
        0.6, "guided matching: smallest descriptor similarity of a pair (cosine)", low=-1, high=1)
    guided_global_mutual: bool = setting(
        False, "guided matching: each pair must also be mutual nearest neighbours over all keypoints")
    pnp: PnpParams = section(
        lambda: PnpParams(min_inliers=10, min_inlier_ratio=0.0, max_median_reprojection_px=3.0),
        "PnP of one keyframe's depth-lifted keypoints into the other")


@dataclass(frozen=True)
class ConnectivityParams(Settings):
    """Connectivity (reachability) parameters."""

    max_line_of_sight_m: float = setting(
        3.0, "keyframes this close on the ground plane are connected when the straight way is free", unit="m", low=0)
    max_line_of_sight_neighbours: int = setting(6, "line-of-sight edges kept per keyframe, nearest first", low=1)


@dataclass(frozen=True)
class MappingParams(Settings):
    """All map-building parameters (config `mapping`)."""

    up: tuple[float, float, float] = setting(
        (0.0, 0.0, 1.0), "unit up vector of the map frame (against gravity)", low=-math.inf)
    covisibility_matcher: str = setting(
        "mnn", "matcher of covisibility.matching: model (mnn = mutual nearest neighbours, ~100x faster than LightGlue)")
    keyframes: KeyframeParams = section(KeyframeParams, "which frames become keyframes")
    occupancy: OccupancyParams = section(OccupancyParams, "the occupancy grid (for planning)")
    covisibility: CovisibilityParams = section(CovisibilityParams, "the covisibility graph (for localization)")
    connectivity: ConnectivityParams = section(ConnectivityParams, "the connectivity graph (for planning)")
    depth: DepthLookupParams = section(DepthLookupParams, "validity gates of the mapping depth at keypoints")
    jpeg_quality: int = setting(
        75, "JPEG quality of keyframe images encoded from raw colour (a source's own JPEGs are kept as they are)",
        low=1, high=100)
    stored_keypoints: int = setting(
        0, "keep only the strongest N keypoints of each keyframe in the map (0 = all)", low=0)
    descriptor_bytes: int = setting(
        32, "bytes per stored local descriptor: product-quantiser sub-codes (must divide D), or 0 = int8 codes", low=0,
        high=4096)
    merge: MergeParams = section(MergeParams, "`litevloc map merge`: joining sessions mapped in different frames")
    update: UpdateParams = section(UpdateParams, "`litevloc map update`: refreshing a map from a new session")
    diff: DiffParams = section(DiffParams, "`litevloc map diff`: comparing two versions of a map")

    def check_relations(self) -> None:
        n = float(np.linalg.norm(self.up))
        if not np.isfinite(n) or n < 1e-6:
            raise ValueError(f"up must be a non-zero vector, got {self.up}")
