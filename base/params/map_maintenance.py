"""Parameters of the maps that live on: merging sessions, updating a map from a new session and
comparing two versions (config `mapping.merge`, `mapping.update`, `mapping.diff`; the algorithms
are `litevloc.pipelines.topomap.merge`, `.update` and `.diff`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from litevloc.base.params.localization import PnpParams
from litevloc.base.settings import Settings, section, setting


@dataclass(frozen=True)
class MergeParams(Settings):
    """Cross-session linking, robust alignment and de-duplication (metres, degrees, pixels)."""

    vpr_top_k: int = setting(3, "map A keyframes tried per map B keyframe (its VPR top-k)", low=1)
    landmark_neighbours: int = setting(2, "covisible B keyframes used to triangulate a B keyframe's keypoints", low=1)
    min_parallax_deg: float = setting(
        1.0, "rays triangulating a landmark must differ by at least this", unit="deg", low=0, low_open=True)
    max_triangulation_px: float = setting(
        2.0, "largest reprojection error of a landmark in both B views", unit="px", low=0, low_open=True)
    min_landmarks: int = setting(30, "B keyframes with fewer landmarks than this are not linked", low=1)
    min_link_inliers: int = setting(30, "PnP inliers a cross-session link needs", low=1)
    min_links: int = setting(3, "consistent links needed to align two sessions", low=1)
    link_sigma_m: float = setting(
        0.05, "prior noise of one link's translation before graduated non-convexity weighs it", unit="m", low=0,
        low_open=True)
    link_sigma_deg: float = setting(1.0, "prior noise of one link's rotation", unit="deg", low=0, low_open=True)
    consistent_m: float = setting(
        0.2, "a link whose translation lies within this of the alignment counts as consistent", unit="m", low=0,
        low_open=True)
    consistent_deg: float = setting(
        3.0, "a link whose rotation lies within this of the alignment counts as consistent", unit="deg", low=0,
        low_open=True)
    max_up_disagreement_deg: float = setting(
        3.0, "largest angle between the sessions' ground planes after alignment", unit="deg", low=0, low_open=True)
    duplicate_radius_m: float = setting(
        0.3, "a B keyframe this close to an A keyframe, and within duplicate_angle_deg of its view, is dropped as a "
        "duplicate", unit="m", low=0, low_open=True)
    duplicate_angle_deg: float = setting(
        20.0, "a B keyframe within duplicate_radius_m of an A keyframe and looking within this angle of it is dropped "
        "as a duplicate", unit="deg", low=0, low_open=True)
    connect_m: float = setting(
        2.0, "cross-session connectivity: free straight segments up to this length", unit="m", low=0, low_open=True)
    connect_neighbours: int = setting(6, "cross-session connectivity edges per keyframe at most", low=1)
    pnp: PnpParams = section(
        lambda: PnpParams(min_inliers=30, min_inlier_ratio=0.0, max_median_reprojection_px=3.0),
        "PnP of a B keyframe's landmarks in an A keyframe (the link's verification)")


@dataclass(frozen=True)
class ReplaceParams(Settings):
    """Replacing changed places' keyframes, judged on the session's other frames there (counts)."""

    enabled: bool = setting(
        True, "a changed-place candidate replaces the stale keyframes of its place (false: it is only added)")
    held_out_frames: int = setting(
        5, "the session's other frames at a candidate's place that judge it, nearest first", low=1)
    min_held_out: int = setting(
        1, "with fewer held-out frames a candidate replaces nothing and is added only below max_per_place", low=1)
    min_gain: float = setting(
        10.0, "a candidate must explain this many more held-out matches (median) than the best old keyframe there",
        low=0)
    max_per_place: int = setting(
        2, "keyframes at most at one place (within place_radius_m and place_angle_deg of a candidate)", low=1)
    new_places: bool = setting(
        True, "a new-place candidate also replaces the stale keyframes within match_radius_m that it explains")


@dataclass(frozen=True)
class UpdateParams(Settings):
    """Change detection and keyframe addition/retirement (metres, degrees, pixels, counts)."""

    place_radius_m: float = setting(
        0.5, "a keyframe covers the places within this distance of it (and within place_angle_deg of its axis)",
        unit="m", low=0, low_open=True)
    place_angle_deg: float = setting(
        30.0, "a keyframe covers the places seen within this angle of its optical axis (and within place_radius_m)",
        unit="deg", low=0, low_open=True)
    match_radius_m: float = setting(
        1.5, "keyframes this close may show a frame's place as known by their matches (the LL reach)", unit="m", low=0,
        low_open=True)
    nodes_checked: int = setting(3, "covering keyframes matched per frame, nearest first", low=1)
    reprojection_px: float = setting(
        4.0, "a match is explained by the frame's pose when it reprojects within this", unit="px", low=0, low_open=True)
    matching: Literal["guided", "model"] = setting(
        "guided", "frame-keyframe matching: 'guided' by projecting with the pose (ms), 'model' runs the matcher")
    guided_min_similarity: float = setting(
        0.6, "smallest descriptor similarity of a guided pair (cosine)", low=-1, high=1)
    changed_max_consistent: int = setting(
        40, "a place whose keyframes explain fewer matches than this is changed or new (above retire_max_consistent)",
        low=0)
    mapped_view: bool = setting(
        True, "a frame no keyframe covers is a new place only where the map's keyframes did not already see its view "
        "(mapped_view_share); one they saw is a mapped place the map no longer matches")
    mapped_view_share: float = setting(
        0.8, "share of a frame's view (its keypoints' ground-plane cells and heading bins, as map building counts "
        "coverage) the map's keyframes must have seen for the frame to be at a mapped place", low=0, high=1,
        low_open=True)
    retire_max_consistent: int = setting(
        15, "a keyframe explaining at most this many matches of well-matching frames is retired", low=0)
    retire_min_visits: int = setting(2, "visits by well-matching frames before a keyframe may be retired", low=1)
    min_spacing_m: float = setting(
        0.5,
        "added keyframes lie at least this far from each other, or look min_spacing_deg differently (= place_radius_m)",
        unit="m", low=0, low_open=True)
    min_spacing_deg: float = setting(
        30.0, "added keyframes look at least this differently from each other, or lie min_spacing_m apart (= "
        "place_angle_deg)", unit="deg", low=0, low_open=True)
    align_every: int = setting(5, "a posed session is aligned to the map by localizing every this-many-th frame", low=1)
    align_frames: int = setting(
        40, "the alignment of a posed session stops once this many of its frames localized", low=1)
    replace: ReplaceParams = section(ReplaceParams, "changed places: which stale keyframes a new one replaces")

    def check_relations(self) -> None:
        if self.match_radius_m < self.place_radius_m:
            raise ValueError("match_radius_m must be >= place_radius_m")
        if not self.retire_max_consistent < self.changed_max_consistent:
            raise ValueError("0 <= retire_max_consistent < changed_max_consistent required")


@dataclass(frozen=True)
class DiffParams(Settings):
    """Tolerances of the diff between two versions of a map (metres, degrees)."""

    moved_m: float = setting(
        0.01, "a kept keyframe moved more than this counts as moved", unit="m", low=0, low_open=True)
    moved_deg: float = setting(
        0.5, "a kept keyframe turned more than this counts as moved", unit="deg", low=0, low_open=True)
    place_radius_m: float = setting(
        0.5, "a keyframe place is still in the other map when one of its keyframes lies this close and within "
        "place_angle_deg", unit="m", low=0, low_open=True)
    place_angle_deg: float = setting(
        45.0, "a keyframe place is still in the other map when one of its keyframes looks within this angle and "
        "place_radius_m", unit="deg", low=0, low_open=True)
