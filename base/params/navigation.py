"""Goal-localization and subgoal-tracking parameters of the planner (config `planner`;
used by `litevloc.pipelines.navigation.planner`)."""

from __future__ import annotations

from dataclasses import dataclass

from litevloc.base.params.localization import PnpMethod, PnpParams


@dataclass(frozen=True)
class GoalParams:
    """Goal localization parameters."""

    # keyframes retrieved by VPR for a goal image and verified
    top_k: int = 5
    # this many keyframes most similar by VPR re-ordered by mutual-nearest-neighbour count before the top_k (0 = off)
    rerank_depth: int = 40
    # cosine similarity of the descriptors a mutual nearest neighbour of that count needs
    rerank_min_similarity: float = 0.7
    # essential-matrix inliers that verify a goal image's place
    min_inliers: int = 25
    # essential-matrix RANSAC threshold (pixels)
    ransac_px: float = 2.0
    # RANSAC seed
    seed: int = 0
    # metric goal pose (PnP against the keyframe's depth-lifted keypoints) needs this many inliers
    pose_min_inliers: int = 20
    # metric goal pose: PnP RANSAC threshold (pixels)
    pose_px: float = 4.0
    # metric goal pose: must lie within this of its keyframe (m)
    pose_max_m: float = 5.0
    # metric goal pose: OpenCV minimal solver inside the PnP RANSAC
    pose_method: PnpMethod = "epnp"
    # metric goal pose: PnP RANSAC iterations at most
    pose_iterations: int = 1000
    # metric goal pose: PnP RANSAC confidence
    pose_confidence: float = 0.999
    # a goal pose within agree_m / agree_deg of its keyframe must explain this share of the keyframe's keypoints in view
    pose_min_explained: float = 0.2
    # a candidate verifies a place only with this many PnP support points off the floor/ceiling band (0 = off)
    pose_min_distinct: int = 10
    # the best verified candidate, where its own keyframe gives no pose, is posed with its covisible candidates' points
    pose_pool_covisible: bool = True
    # a verified candidate without a pose is stood for by the strongest posed verified one within this (m; 0 = off)
    pose_fallback_m: float = 5.0
    # drop a goal pose whose camera lies in an occupied cell of the map's grid (inside a wall)
    pose_outside_obstacles: bool = True
    # in a map with keypoint depth, refuse a goal verified at a node without a metric pose (its place cannot be checked)
    require_pose: bool = True
    # refuse a goal as ambiguous when another place has more than 1/this of the chosen place's support (0 = off)
    ambiguity_ratio: float = 2.0
    # height of the floor/ceiling band whose support an ambiguous goal's second look ignores (m; 0 = off)
    ambiguity_band_m: float = 0.04
    # goal poses within this of each other along the floor are one place; within this of a keyframe, at its view (m)
    agree_m: float = 0.5
    # ... and within this rotation (degrees)
    agree_deg: float = 20.0
    # a candidate whose inliers lie within this RMS of one plane matched a flat patch (m; 0 = off)
    planar_rms_m: float = 0.03
    # a flat-patch candidate verifies a place only with this many times min_inliers
    planar_factor: float = 2.0
    # the candidates with most essential-matrix inliers that bring their neighbour keyframes to verify too
    expand_from: int = 2
    # neighbour keyframes each such candidate brings at most (0 = no expansion)
    expand_k: int = 4
    # a neighbour stands within this distance of the candidate's keyframe (m)
    expand_m: float = 2.5
    # ... and its optical axis within this angle of the candidate's (degrees)
    expand_deg: float = 60.0
    # essential-matrix inliers a candidate needs to bring its neighbours
    expand_min_inliers: int = 15

    def __post_init__(self) -> None:
        if self.top_k < 1 or self.min_inliers < 8 or self.ransac_px <= 0:
            raise ValueError("top_k >= 1, min_inliers >= 8 and ransac_px > 0 required")
        if self.rerank_depth < 0 or not -1 <= self.rerank_min_similarity <= 1:
            raise ValueError("rerank_depth >= 0 and rerank_min_similarity in [-1, 1] required")
        if self.pose_min_inliers < 6 or self.pose_px <= 0 or self.pose_max_m <= 0:
            raise ValueError("pose_min_inliers >= 6, pose_px > 0 and pose_max_m > 0 required")
        if not 0 <= self.pose_min_explained <= 1:
            raise ValueError("pose_min_explained must be in [0, 1] (0 = off)")
        if self.ambiguity_ratio < 0 or 0 < self.ambiguity_ratio < 1:
            raise ValueError("ambiguity_ratio must be 0 (off) or >= 1")
        if not self.pose_fallback_m >= 0:
            raise ValueError("pose_fallback_m must be >= 0 (0 = off)")
        if self.pose_min_distinct < 0:
            raise ValueError("pose_min_distinct must be >= 0 (0 = off)")
        if self.ambiguity_band_m < 0:
            raise ValueError("ambiguity_band_m must be >= 0 (0 = off)")
        if self.agree_m <= 0 or not 0 < self.agree_deg <= 180:
            raise ValueError("agree_m > 0 and 0 < agree_deg <= 180 required")
        if self.planar_rms_m < 0 or not self.planar_factor >= 1:
            raise ValueError("planar_rms_m >= 0 (0 = off) and planar_factor >= 1 required")
        if self.expand_from < 0 or self.expand_k < 0 or self.expand_m <= 0 or not 0 < self.expand_deg <= 180 \
                or self.expand_min_inliers < 0:
            raise ValueError("expand_from, expand_k, expand_min_inliers >= 0, expand_m > 0 and 0 < expand_deg <= 180 "
                             "required")
        self.pose_pnp()  # the goal pose's PnP settings are valid

    def pose_pnp(self) -> PnpParams:
        """The PnP settings of the metric goal pose: RANSAC with `pose_*`, then a refinement on
        RANSAC's consensus set; its count (`PnpResult.n_ransac_inliers`) is the goal pose's
        support, so the re-scoring gates are open."""
        return PnpParams(method=self.pose_method, reprojection_px=self.pose_px, iterations=self.pose_iterations,
                         confidence=self.pose_confidence, min_inliers=self.pose_min_inliers, min_inlier_ratio=0.0,
                         max_median_reprojection_px=float("inf"), seed=self.seed)


@dataclass(frozen=True)
class TrackerParams:
    """Subgoal tracking along the planned node path (metres, seconds, degrees). A leg is the way to
    the next node: the straight line, or the metres the mapping pass drove along that edge where
    longer (consecutive keyframes rooms apart)."""

    # a node is reached within this distance (m)
    reach_m: float = 0.5
    # farther than this from the path replans (m)
    stray_m: float = 2.0
    # after the goal node, drive on to the goal image's own place along a path on the map's occupancy grid
    final_approach: bool = True
    # the final approach's grid path keeps this far from occupied cells (m; the robot's radius)
    approach_radius_m: float = 0.3
    # a goal place inside an obstacle's margin is approached at the nearest free cell within this (m)
    approach_snap_m: float = 0.5
    # a goal place whose grid path from its node is this much longer than the straight line is refused (m)
    approach_detour_m: float = 2.0
    # advance past a reached node only when the way on is clear for a robot of this radius (m; 0 = off)
    clearance_m: float = 0.45
    # a node behind a wall on the grid is reached along grid turns this much longer than the leg at most (m; 0 = off)
    leg_detour_m: float = 6.0
    # a goal fails ("no progress") when not stall_progress_m closer within this (s of sensor time; 0 = off)
    stall_s: float = 30.0
    # progress that resets the stall clock (m)
    stall_progress_m: float = 0.25
    # an edge driven against the map's views costs this many times its length (1 = plan by length alone)
    against_view_cost: float = 10.0
    # an edge is driven against the map's views beyond this angle from both keyframes' axes (degrees)
    against_view_deg: float = 120.0

    def __post_init__(self) -> None:
        if self.reach_m <= 0 or self.stray_m <= self.reach_m or self.clearance_m < 0 or self.leg_detour_m < 0:
            raise ValueError("need 0 < reach_m < stray_m, clearance_m >= 0 and leg_detour_m >= 0")
        if self.approach_radius_m < 0 or self.approach_snap_m < 0 or self.approach_detour_m <= 0:
            raise ValueError("need approach_radius_m >= 0, approach_snap_m >= 0 and approach_detour_m > 0")
        if not (1.0 <= self.against_view_cost < float("inf")) or not 0 < self.against_view_deg <= 180:
            raise ValueError("need a finite against_view_cost >= 1 (1 = off) and 0 < against_view_deg <= 180")
        if not (0 <= self.stall_s < float("inf")) or self.stall_progress_m <= 0:
            raise ValueError("need a finite stall_s >= 0 (0 = off) and stall_progress_m > 0")


@dataclass(frozen=True)
class OpeningParams:
    """Unmapped openings of a map's occupancy grid (`pipelines.topomap.openings`: listed by
    `map build` and `map info`, where a mapping team should go back)."""

    # narrowest opening listed (m): the frontier cells' longest extent; below a robot's width
    min_width_m: float = 0.6
    # least unknown area (m^2) an opening must lead to within look_m (a shadow behind furniture is smaller)
    min_unknown_m2: float = 1.0
    # how far beyond the frontier (m) the unknown area is counted
    look_m: float = 1.5
    # free space is closed over unknown gaps up to this size (m): a floor or wall seen from afar is speckled
    close_m: float = 0.2

    def __post_init__(self) -> None:
        if self.min_width_m <= 0 or self.min_unknown_m2 < 0 or self.look_m <= 0 or self.close_m < 0:
            raise ValueError("need min_width_m > 0, min_unknown_m2 >= 0, look_m > 0 and close_m >= 0")
