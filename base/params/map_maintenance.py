"""Parameters of the maps that live on: merging sessions, updating a map from a new session and
comparing two versions (config `mapping.merge`, `mapping.update`, `mapping.diff`; the algorithms
are `litevloc.pipelines.topomap.merge`, `.update` and `.diff`)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

from litevloc.base.params.localization import PnpParams


@dataclass(frozen=True)
class MergeParams:
    """Cross-session linking, robust alignment and de-duplication (metres, degrees, pixels)."""

    # A keyframes tried per B keyframe (its VPR top-k)
    vpr_top_k: int = 3
    # covisible B keyframes used to triangulate a B keyframe's keypoints
    landmark_neighbours: int = 2
    # triangulated rays must differ by at least this (degrees)
    min_parallax_deg: float = 1.0
    # largest reprojection error of a landmark in both B views (pixels)
    max_triangulation_px: float = 2.0
    # B keyframes with fewer landmarks are not linked
    min_landmarks: int = 30
    # PnP inliers a cross-session link needs
    min_link_inliers: int = 30
    # consistent links needed to align two sessions
    min_links: int = 3
    # prior noise of one link's translation before graduated non-convexity weighs it (m)
    link_sigma_m: float = 0.05
    # prior noise of one link's rotation (degrees)
    link_sigma_deg: float = 1.0
    # a link whose translation lies within this of the alignment counts as consistent (m)
    consistent_m: float = 0.2
    # ... and whose rotation lies within this (degrees)
    consistent_deg: float = 3.0
    # largest angle between the sessions' ground planes after alignment (degrees)
    max_up_disagreement_deg: float = 3.0
    # a B keyframe this close to an A keyframe (m) ...
    duplicate_radius_m: float = 0.3
    # ... and looking within this angle of it (degrees) is dropped as a duplicate
    duplicate_angle_deg: float = 20.0
    # cross-session connectivity: free straight segments up to this length (m)
    connect_m: float = 2.0
    # cross-session connectivity edges per keyframe at most
    connect_neighbours: int = 6
    # PnP of a B keyframe's landmarks in an A keyframe (the link's verification)
    pnp: PnpParams = field(default_factory=lambda: PnpParams(
        min_inliers=30, min_inlier_ratio=0.0, max_median_reprojection_px=3.0))

    def __post_init__(self) -> None:
        for name in ("vpr_top_k", "landmark_neighbours", "min_landmarks", "min_link_inliers", "min_links",
                     "connect_neighbours"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1")
        for name in ("min_parallax_deg", "max_triangulation_px", "link_sigma_m", "link_sigma_deg", "consistent_m",
                     "consistent_deg", "max_up_disagreement_deg", "duplicate_radius_m", "duplicate_angle_deg",
                     "connect_m"):
            v = getattr(self, name)
            if not (v > 0 and math.isfinite(v)):
                raise ValueError(f"{name} must be a finite number > 0, got {v}")


@dataclass(frozen=True)
class UpdateParams:
    """Change detection and keyframe addition/retirement (metres, degrees, pixels, counts)."""

    # a keyframe covers the places within this distance of it (m) ...
    place_radius_m: float = 0.5
    # ... seen within this angle of its optical axis (degrees)
    place_angle_deg: float = 30.0
    # keyframes this close may show a frame's place as known by their matches (m; the LL reach)
    match_radius_m: float = 1.5
    # covering keyframes matched per frame, nearest first
    nodes_checked: int = 3
    # a match is explained by the frame's pose when it reprojects within this (pixels)
    reprojection_px: float = 4.0
    # frame-keyframe matching: "guided" by projecting with the pose (ms), "model" runs the matcher
    matching: Literal["guided", "model"] = "guided"
    # smallest descriptor similarity of a guided pair (cosine)
    guided_min_similarity: float = 0.6
    # a place whose keyframes explain fewer matches than this is changed (or new)
    changed_max_consistent: int = 40
    # a keyframe explaining at most this many matches of well-matching frames is retired
    retire_max_consistent: int = 15
    # visits by well-matching frames before a keyframe may be retired
    retire_min_visits: int = 2
    # added keyframes lie at least this far from each other (m; = place_radius_m)
    min_spacing_m: float = 0.5
    # ... or look at least this differently (degrees; = place_angle_deg)
    min_spacing_deg: float = 30.0
    # a posed session is aligned to the map by localizing every this-many-th frame (frame index)
    align_every: int = 5
    # ... until this many frames localized
    align_frames: int = 40

    def __post_init__(self) -> None:
        for name in ("place_radius_m", "place_angle_deg", "match_radius_m", "reprojection_px", "min_spacing_m",
                     "min_spacing_deg"):
            v = getattr(self, name)
            if not (v > 0 and math.isfinite(v)):
                raise ValueError(f"{name} must be a finite number > 0, got {v}")
        if self.match_radius_m < self.place_radius_m:
            raise ValueError("match_radius_m must be >= place_radius_m")
        if self.matching not in ("guided", "model"):
            raise ValueError(f"matching must be 'guided' or 'model', got {self.matching!r}")
        if not (-1.0 <= self.guided_min_similarity <= 1.0):
            raise ValueError(f"guided_min_similarity must be in [-1, 1], got {self.guided_min_similarity}")
        if min(self.nodes_checked, self.retire_min_visits, self.align_every, self.align_frames) < 1:
            raise ValueError("nodes_checked, retire_min_visits, align_every and align_frames must be >= 1")
        if not (0 <= self.retire_max_consistent < self.changed_max_consistent):
            raise ValueError("0 <= retire_max_consistent < changed_max_consistent required")


@dataclass(frozen=True)
class DiffParams:
    """Tolerances of the diff between two versions of a map (metres, degrees)."""

    # a kept keyframe moved more than this counts as moved (m)
    moved_m: float = 0.01
    # ... or turned more than this (degrees)
    moved_deg: float = 0.5
    # a keyframe place is still in the other map when one of its keyframes lies this close (m) ...
    place_radius_m: float = 0.5
    # ... and looks within this angle of it (degrees)
    place_angle_deg: float = 45.0

    def __post_init__(self) -> None:
        for name in ("moved_m", "moved_deg", "place_radius_m", "place_angle_deg"):
            v = getattr(self, name)
            if not (v > 0 and math.isfinite(v)):
                raise ValueError(f"{name} must be a finite number > 0, got {v}")
