"""Goal-localization and subgoal-tracking parameters of the planner (config `planner`;
used by `litevloc.pipelines.navigation.planner`)."""

from __future__ import annotations

import math
from dataclasses import dataclass

from litevloc.base.params.localization import PnpMethod, PnpParams
from litevloc.base.settings import Settings, setting


@dataclass(frozen=True)
class GoalParams(Settings):
    """Goal localization parameters."""

    top_k: int = setting(5, "keyframes retrieved by VPR for a goal image and verified", low=1)
    rerank_depth: int = setting(
        40, "this many keyframes most similar by VPR are re-ordered by mutual-nearest-neighbour count before the "
        "top_k (0 = off)", low=0)
    rerank_min_similarity: float = setting(
        0.7, "cosine similarity of the descriptors a mutual nearest neighbour of the re-ranking count needs", low=-1,
        high=1)
    min_inliers: int = setting(25, "essential-matrix inliers that verify a goal image's place", low=8)
    ransac_px: float = setting(2.0, "essential-matrix RANSAC threshold", unit="px", low=0, low_open=True)
    seed: int = setting(0, "seed of the goal localization's RANSAC", low=-math.inf)
    pose_min_inliers: int = setting(
        20, "metric goal pose (PnP against the keyframe's depth-lifted keypoints) needs this many inliers", low=6)
    pose_px: float = setting(4.0, "metric goal pose: PnP RANSAC threshold", unit="px", low=0, low_open=True)
    pose_max_m: float = setting(
        5.0, "metric goal pose: must lie within this of its keyframe", unit="m", low=0, low_open=True)
    pose_method: PnpMethod = setting("epnp", "metric goal pose: OpenCV minimal solver inside the PnP RANSAC")
    pose_iterations: int = setting(1000, "metric goal pose: PnP RANSAC iterations at most", low=1)
    pose_confidence: float = setting(
        0.999, "metric goal pose: PnP RANSAC confidence", low=0, low_open=True, high=1, high_open=True)
    pose_min_explained: float = setting(
        0.2, "a goal pose within agree_m / agree_deg of its keyframe must explain this share of the keyframe's "
        "keypoints in view", low=0, high=1)
    pose_min_distinct: int = setting(
        10, "a candidate verifies a place only with this many PnP support points off the floor/ceiling band (0 = off)",
        low=0)
    pose_pool_covisible: bool = setting(
        True, "the best verified candidate, where its own keyframe gives no pose, is posed with its covisible "
        "candidates' points")
    pose_fallback_m: float = setting(
        5.0,
        "a verified candidate without a pose is stood for by the strongest posed verified one within this (0 = off)",
        unit="m", low=0)
    pose_outside_obstacles: bool = setting(
        True, "drop a goal pose whose camera lies in an occupied cell of the map's grid (inside a wall)")
    require_pose: bool = setting(
        True, "in a map with keypoint depth, refuse a goal verified at a node without a metric pose (its place cannot "
        "be checked)")
    ambiguity_ratio: float = setting(
        2.0, "refuse a goal as ambiguous when another place has more than 1/this of the chosen place's support (0 = "
        "off)", low=1, off=0)
    ambiguity_band_m: float = setting(
        0.04, "height of the floor/ceiling band whose support an ambiguous goal's second look ignores (0 = off)",
        unit="m", low=0)
    agree_m: float = setting(
        0.5,
        "goal poses within this of each other along the floor are one place; within this of a keyframe, at its view",
        unit="m", low=0, low_open=True)
    agree_deg: float = setting(
        20.0, "goal poses within this rotation of each other (and agree_m) are one place", unit="deg", low=0,
        low_open=True, high=180)
    planar_rms_m: float = setting(
        0.03, "a candidate whose inliers lie within this RMS of one plane matched a flat patch (0 = off)", unit="m",
        low=0)
    planar_factor: float = setting(
        2.0, "a flat-patch candidate verifies a place only with this many times min_inliers", low=1)
    expand_from: int = setting(
        2, "how many of the candidates with most essential-matrix inliers also bring their neighbour keyframes to be "
        "verified", low=0)
    expand_k: int = setting(4, "neighbour keyframes each expanding candidate brings at most (0 = no expansion)", low=0)
    expand_m: float = setting(
        2.5, "a candidate's neighbour keyframe stands within this distance of the candidate's keyframe", unit="m",
        low=0, low_open=True)
    expand_deg: float = setting(
        60.0, "a candidate's neighbour keyframe has its optical axis within this angle of the candidate's", unit="deg",
        low=0, low_open=True, high=180)
    expand_min_inliers: int = setting(15, "essential-matrix inliers a candidate needs to bring its neighbours", low=0)

    def check_relations(self) -> None:
        self.pose_pnp()  # the goal pose's PnP settings are valid

    def pose_pnp(self) -> PnpParams:
        """The PnP settings of the metric goal pose: RANSAC with `pose_*`, then a refinement on
        RANSAC's consensus set; its count (`PnpResult.n_ransac_inliers`) is the goal pose's
        support, so the re-scoring gates are open."""
        return PnpParams(method=self.pose_method, reprojection_px=self.pose_px, iterations=self.pose_iterations,
                         confidence=self.pose_confidence, min_inliers=self.pose_min_inliers, min_inlier_ratio=0.0,
                         max_median_reprojection_px=float("inf"), seed=self.seed)


@dataclass(frozen=True)
class TrackerParams(Settings):
    """Subgoal tracking along the planned node path (metres, seconds, degrees). A leg is the way to
    the next node: the straight line, or the metres the mapping pass drove along that edge where
    longer (consecutive keyframes rooms apart)."""

    reach_m: float = setting(0.5, "a path node is reached within this distance", unit="m", low=0, low_open=True)
    stray_m: float = setting(
        2.0, "farther than this from the path replans (above reach_m)", unit="m", low=0, low_open=True)
    final_approach: bool = setting(
        True, "after the goal node, drive on to the goal image's own place along a path on the map's occupancy grid")
    approach_radius_m: float = setting(
        0.3, "the final approach's grid path keeps this far from occupied cells (the robot's radius)", unit="m", low=0)
    approach_snap_m: float = setting(
        0.5, "a goal place inside an obstacle's margin is approached at the nearest free cell within this", unit="m",
        low=0)
    approach_detour_m: float = setting(
        2.0, "a goal place whose grid path from its node is this much longer than the straight line is refused",
        unit="m", low=0, low_open=True)
    clearance_m: float = setting(
        0.45, "advance past a reached node only when the way on is clear for a robot of this radius (0 = off)",
        unit="m", low=0)
    leg_detour_m: float = setting(
        6.0,
        "a node behind a wall on the grid is reached along grid turns this much longer than the leg at most (0 = off)",
        unit="m", low=0)
    stall_s: float = setting(
        30.0, "a goal fails ('no progress') when not stall_progress_m closer within this much sensor time (0 = off)",
        unit="s", low=0)
    stall_progress_m: float = setting(
        0.25, "progress towards the goal that resets the stall clock", unit="m", low=0, low_open=True)
    against_view_cost: float = setting(
        10.0, "an edge driven against the map's views costs this many times its length (1 = plan by length alone)",
        low=1)
    against_view_deg: float = setting(
        120.0, "an edge is driven against the map's views beyond this angle from both keyframes' axes", unit="deg",
        low=0, low_open=True, high=180)

    def check_relations(self) -> None:
        if self.stray_m <= self.reach_m:
            raise ValueError("need 0 < reach_m < stray_m")


@dataclass(frozen=True)
class OpeningParams(Settings):
    """Unmapped openings of a map's occupancy grid (`pipelines.topomap.openings`: listed by
    `map build` and `map info`, where a mapping team should go back)."""

    min_width_m: float = setting(
        0.6, "narrowest opening listed: the frontier cells' longest extent; below a robot's width", unit="m", low=0,
        low_open=True)
    min_unknown_m2: float = setting(
        1.0, "least unknown area an opening must lead to within look_m (a shadow behind furniture is smaller)",
        unit="m^2", low=0)
    look_m: float = setting(
        1.5, "how far beyond the frontier the unknown area is counted", unit="m", low=0, low_open=True)
    close_m: float = setting(
        0.2, "free space is closed over unknown gaps up to this size: a floor or wall seen from afar is speckled",
        unit="m", low=0)
