"""Parameters of localization: depth lookup, PnP, joint refinement, GL/LL and the state machine
(config `localization`; the algorithms are `pipelines.depth_lookup`, `pipelines.pnp`,
`pipelines.localization.refine` and `pipelines.localization.vloc`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np

PnpMethod = Literal["p3p", "ap3p", "sqpnp", "epnp", "usac_magsac"]


@dataclass(frozen=True)
class DepthLookupParams:
    """Validity gates for depth at keypoints (metres)."""

    # nearer depth is invalid (m)
    min_depth: float = 0.1
    # farther depth is invalid (m)
    max_depth: float = 10.0
    # a keypoint's depth must agree with its neighbours' within abs_tol + rel_tol x depth (m)
    abs_tol: float = 0.03
    # relative part of that tolerance (fraction of the depth)
    rel_tol: float = 0.03

    def __post_init__(self) -> None:
        if not (0 <= self.min_depth < self.max_depth):
            raise ValueError(f"need 0 <= min_depth < max_depth, got {self.min_depth}, {self.max_depth}")
        if self.abs_tol < 0 or self.rel_tol < 0:
            raise ValueError("abs_tol and rel_tol must be >= 0")


@dataclass(frozen=True)
class PnpParams:
    """RANSAC settings and acceptance gates (defaults follow the published system)."""

    # OpenCV minimal solver inside RANSAC
    method: PnpMethod = "ap3p"
    # RANSAC inlier threshold (pixels)
    reprojection_px: float = 3.0
    # RANSAC iterations at most
    iterations: int = 1000
    # RANSAC confidence
    confidence: float = 0.9999
    # Levenberg-Marquardt refinement on the inliers
    refine_lm: bool = True
    # a pose needs at least this many inliers
    min_inliers: int = 40
    # ... and at least this share of the matches as inliers
    min_inlier_ratio: float = 0.2
    # ... and a median inlier reprojection error of at most this (pixels)
    max_median_reprojection_px: float = 2.0
    # RANSAC seed (results are reproducible)
    seed: int = 0
    # smallest translation sigma of a PnP covariance (m)
    min_sigma_trans_m: float = 0.01
    # smallest rotation sigma of a PnP covariance (rad)
    min_sigma_rot_rad: float = float(np.radians(0.5))

    def __post_init__(self) -> None:
        if self.method not in ("p3p", "ap3p", "sqpnp", "epnp", "usac_magsac"):
            raise ValueError(f"unknown PnP method {self.method!r}")
        if self.reprojection_px <= 0 or self.iterations <= 0 or not (0 < self.confidence < 1):
            raise ValueError("reprojection_px and iterations must be > 0, confidence in (0, 1)")
        if self.min_inliers < 4 or not (0 <= self.min_inlier_ratio <= 1):
            raise ValueError("min_inliers must be >= 4 and min_inlier_ratio in [0, 1]")


@dataclass(frozen=True)
class RefineParams:
    """Joint multi-keyframe refinement and its acceptance (pixels, metres, degrees)."""

    # keyframes in the joint solve, the PnP keyframe included
    max_keyframes: int = 3
    # keyframes that must each be consistent with the joint pose
    min_keyframes: int = 2
    # inliers under the joint pose for a keyframe to count as consistent
    min_keyframe_inliers: int = 15
    # reprojection threshold of an inlier (raw pixels)
    inlier_px: float = 3.0
    # a correspondence enters the solve if within this of the initial pose (pixels)
    gate_px: float = 8.0
    # robust loss of the joint solve
    loss: Literal["cauchy", "huber", "soft_l1"] = "cauchy"
    # robust loss scale (whitened units, sigmas)
    loss_scale: float = 2.0
    # keypoint position noise (pixels, 1 sigma)
    keypoint_sigma_px: float = 1.0
    # depth noise sigma_z = a z^2 + b: the quadratic coefficient a (1/m)
    depth_sigma_a: float = 0.0015
    # depth noise constant b (m)
    depth_sigma_b: float = 0.002
    # use the map's depth at keyframe keypoints: 3D residuals instead of reprojections where it has depth
    map_depth: bool = True
    # the joint pose may move at most this far from the initial pose (m)
    max_shift_m: float = 0.25
    # ... and turn at most this far (degrees)
    max_shift_deg: float = 5.0
    # covariance: systematic translation error, constant part (m)
    sigma_sys_t_m: float = 0.0
    # covariance: systematic rotation error, constant part (degrees)
    sigma_sys_r_deg: float = 0.0
    # covariance: systematic translation error per radian between live view and keyframes (m/rad)
    sigma_sys_t_per_rad: float = 0.083
    # covariance: systematic rotation error per radian between live view and keyframes (rad/rad)
    sigma_sys_r_per_rad: float = 0.0334
    # covariance: systematic translation error per metre from the keyframes (m/m)
    sigma_sys_t_per_m: float = 0.022
    # covariance: systematic rotation error per metre from the keyframes (deg/m)
    sigma_sys_r_deg_per_m: float = 0.92
    # smallest translation sigma of the covariance (m)
    min_sigma_t_m: float = 0.002
    # smallest rotation sigma of the covariance (degrees)
    min_sigma_r_deg: float = 0.05
    # function evaluations of the least-squares solve at most
    max_nfev: int = 30
    # matching the extra keyframes: "guided" by projecting with the initial pose (~1 ms), "model" (~100 ms)
    extra_matching: Literal["guided", "model"] = "guided"
    # guided matching: search radius around the projected point (pixels)
    guided_radius_px: float = 8.0
    # guided matching: each pair must also be mutual nearest neighbours over all keypoints
    guided_global_mutual: bool = True
    # guided matching: smallest descriptor similarity of a pair (cosine)
    guided_min_similarity: float = 0.6

    def __post_init__(self) -> None:
        if self.max_keyframes < 1 or not (1 <= self.min_keyframes <= self.max_keyframes):
            raise ValueError("need max_keyframes >= 1 and 1 <= min_keyframes <= max_keyframes")
        if self.min_keyframe_inliers < 1 or self.inlier_px <= 0 or self.gate_px < self.inlier_px:
            raise ValueError("need min_keyframe_inliers >= 1, inlier_px > 0 and gate_px >= inlier_px")
        if self.extra_matching not in ("guided", "model"):
            raise ValueError(f"unknown extra_matching {self.extra_matching!r} (guided | model)")
        if self.guided_radius_px <= 0 or not (-1 <= self.guided_min_similarity <= 1):
            raise ValueError("need guided_radius_px > 0 and guided_min_similarity in [-1, 1]")
        if self.loss not in ("cauchy", "huber", "soft_l1"):
            raise ValueError(f"unknown loss {self.loss!r}")
        for name in ("loss_scale", "keypoint_sigma_px", "max_shift_m", "max_shift_deg", "max_nfev"):
            if getattr(self, name) <= 0:
                raise ValueError(f"{name} must be > 0")
        for name in ("depth_sigma_a", "depth_sigma_b", "sigma_sys_t_m", "sigma_sys_r_deg", "sigma_sys_t_per_rad",
                     "sigma_sys_r_per_rad", "sigma_sys_t_per_m", "sigma_sys_r_deg_per_m",
                     "min_sigma_t_m", "min_sigma_r_deg"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name} must be >= 0")


@dataclass(frozen=True)
class LocalizationParams:
    """Parameters of GL, LL and the state machine (metres, degrees)."""

    # GL: keyframes retrieved by VPR and verified, best first
    gl_top_k: int = 10
    # > 0: GL's time budget per query (ms); a next candidate is tried only while it fits
    gl_time_budget_ms: float = 0.0
    # GL tries its candidates in the order of their mutual-nearest-neighbour count with the live frame
    gl_rerank: bool = True
    # smallest descriptor similarity of a mutual nearest neighbour counted by the re-ranking (cosine)
    gl_rerank_min_similarity: float = 0.7
    # VPR shortlist the re-ranking orders, its first gl_top_k verified (0 = gl_top_k)
    gl_rerank_depth: int = 0
    # once tracked, a GL query may cost this many times the mean LL query (0 = no bound)
    lost_cost_ratio: float = 2.0
    # a GL pose must also explain matches with a second keyframe
    gl_confirm: bool = True
    # an LL pose must also explain matches with a second keyframe (unless confirm_skip_* applies)
    ll_confirm: bool = True
    # a GL pose with this many inliers that no second keyframe sees is a provisional vote (0 = off)
    gl_vote_min_inliers: int = 60
    # a GL candidate whose inliers span less height than this rests on floor or ceiling: refused (m; 0 = off)
    gl_min_support_height_m: float = 0.15
    # an LL pose this close to a fresh prior needs no second keyframe (m)
    confirm_skip_within_m: float = 0.2
    # ... and this close in rotation (degrees)
    confirm_skip_within_deg: float = 5.0
    # a prior is fresh up to this age (s)
    confirm_skip_max_age_s: float = 0.5
    # LL prior gate: an LL pose must lie this close to a last-VLoc-pose prior (m) ...
    prior_gate_m: float = 0.75
    # ... plus this much per second of the prior's age (m/s)
    prior_gate_rate_mps: float = 1.5
    # ... and within this rotation of it (degrees)
    prior_gate_deg: float = 30.0
    # a fused prior's gate grows at this rate per second since the last fix (m/s: odometry drift)
    prior_gate_rate_fused_mps: float = 0.1
    # ... but no more than this fraction of the odometry's path since that fix, where known (at rest: no growth)
    prior_gate_drift_fused: float = 0.2
    # a fused prior's gate starts from this radius (m)
    prior_gate_fused_m: float = 0.25
    # with fusion's covariance, a fused prior's gate toward a pose is at most its start + this many sigmas (0 = off)
    prior_gate_sigmas: float = 3.0
    # a GL pose outside a fused prior's gate gives way to a pose LL verifies at the prior's place (repeating places)
    gl_check_prior_place: bool = True
    # a pose outside a fused prior's gate (or with a stale prior) waits this long for a repeat (s; 0 = off)
    repeat_within_s: float = 5.0
    # ... or for any time while the prior moved less than this since the held pose (m: a robot at rest, slow GL)
    repeat_within_m: float = 0.1
    # a held pose is repeated when the two agree within this rotation (degrees)
    repeat_deg: float = 5.0
    # LL candidates: keyframes within this distance of the prior (m)
    candidate_radius_m: float = 3.0
    # LL candidates: keyframes looking within this angle of the prior (degrees)
    max_view_angle_deg: float = 90.0
    # LL candidates by place descriptor per query (then the nearest, where they leave it out)
    ll_max_candidates: int = 3
    # LL with a fresh prior: guided matches stand in for the matcher's when at least this many (0 = off)
    ll_guided_min_matches: int = 60
    # consecutive LL failures that make the state LOST (the next query runs GL)
    ll_failures_before_lost: int = 3
    # a prior farther than this from every keyframe sends the query to GL (m)
    gl_trigger_distance_m: float = 7.5
    # an accepted pose must lie this close to its keyframe (m)
    max_distance_to_node_m: float = 5.0
    # matches a candidate needs before PnP
    min_matches: int = 20
    # > 0: a candidate with this many PnP inliers (< pnp.min_inliers) passes if its joint keyframes reach that many
    pooled_min_inliers: int = 20
    # verification and refinement also use the map's depth at keyframe keypoints (off: it verifies aliased places too)
    verify_map_depth: bool = False
    # a GL query that live depth cannot verify is verified again with the map's depth (verify_map_depth for it alone)
    map_depth_fallback: bool = True
    # that second pass: GL refuses a pose another place verifies with >= 1/this of its inliers (0 = gl_distinct_ratio)
    map_depth_fallback_distinct_ratio: float = 2.0
    # without a fresh prior, GL refuses a pose if a candidate at another pose has >= 1/this of its PnP inliers (0 = off)
    gl_distinct_ratio: float = 0.0
    # candidate poses farther apart than this are different places for that test (m)
    gl_distinct_m: float = 0.3
    # ... or turned further apart than this (degrees)
    gl_distinct_deg: float = 10.0
    # candidates verified after the accepted one for that test at most (those with >= 1/ratio of its re-ranking count)
    gl_distinct_max_rivals: int = 3
    # that test skips the later candidates whose PnP on the re-ranking's matches (no model run) agrees with that pose
    gl_distinct_screen: bool = True
    # > 0: where that test judges a GL pose, its PnP needs this many inliers instead of pnp.min_inliers
    gl_distinct_min_inliers: int = 0
    # GL refused by every pass: re-verify this many refused candidates at models.second_look_size (0 = off)
    second_look_candidates: int = 2
    # ... LL too (keeps tracking where the first look loses it; its poses are only as good as the prior's gate)
    second_look_local: bool = True
    # ... only candidates whose first look found at least this many PnP inliers (the cost goes where a pose may be)
    second_look_from_inliers: int = 10
    # it refuses a pose putting more than this share of its keyframes' map points in view in front of the live depth
    second_look_max_see_through: float = 0.3
    # ... a pose over it is moved onto the live depth if at most this far (m; 0 = never), then under half that share
    second_look_align_m: float = 0.3
    # ... and turns it at most this much (degrees)
    second_look_align_deg: float = 6.0
    # LL's look: its pose must lie this close to a last-VLoc-pose prior (m, for prior_gate_m; the rate still adds)
    second_look_prior_gate_m: float = 0.25
    # PnP + RANSAC of live keypoints (with live depth) against a keyframe
    pnp: PnpParams = field(default_factory=PnpParams)
    # validity gates of the live depth at keypoints
    depth: DepthLookupParams = field(default_factory=DepthLookupParams)
    # joint multi-keyframe refinement: a pose's confirmation by its keyframe's covisible neighbours
    refine: RefineParams = field(default_factory=RefineParams)

    def __post_init__(self) -> None:
        if self.ll_guided_min_matches < 0:
            raise ValueError(f"ll_guided_min_matches must be >= 0, got {self.ll_guided_min_matches}")
        if self.gl_top_k < 1 or self.ll_max_candidates < 1 or self.ll_failures_before_lost < 1:
            raise ValueError("gl_top_k, ll_max_candidates and ll_failures_before_lost must be >= 1")
        if self.candidate_radius_m <= 0 or not (0 < self.max_view_angle_deg <= 180):
            raise ValueError("candidate_radius_m > 0 and max_view_angle_deg in (0, 180] required")
        if self.gl_vote_min_inliers < 0:
            raise ValueError("gl_vote_min_inliers must be >= 0 (0 = no provisional poses)")
        if self.gl_min_support_height_m < 0:
            raise ValueError("gl_min_support_height_m must be >= 0 (0 = off)")
        if self.gl_time_budget_ms < 0:
            raise ValueError("gl_time_budget_ms must be >= 0 (0 = no budget)")
        if self.lost_cost_ratio < 0:
            raise ValueError("lost_cost_ratio must be >= 0 (0 = no bound)")
        if self.gl_distinct_ratio < 0 or 0 < self.gl_distinct_ratio < 1:
            raise ValueError("gl_distinct_ratio must be 0 (off) or >= 1")
        if self.map_depth_fallback_distinct_ratio < 0 or 0 < self.map_depth_fallback_distinct_ratio < 1:
            raise ValueError("map_depth_fallback_distinct_ratio must be 0 (gl_distinct_ratio) or >= 1")
        if self.gl_distinct_m <= 0 or not 0 < self.gl_distinct_deg <= 180 or self.gl_distinct_max_rivals < 0:
            raise ValueError("need gl_distinct_m > 0, gl_distinct_deg in (0, 180] and gl_distinct_max_rivals >= 0")
        if self.pooled_min_inliers < 0 or 0 < self.pooled_min_inliers < 4:
            raise ValueError("pooled_min_inliers must be 0 (off) or >= 4")
        if self.gl_distinct_min_inliers < 0 or 0 < self.gl_distinct_min_inliers < 4:
            raise ValueError("gl_distinct_min_inliers must be 0 (pnp.min_inliers) or >= 4")
        if self.gl_rerank_depth < 0:
            raise ValueError("gl_rerank_depth must be >= 0")
        if self.second_look_candidates < 0 or self.second_look_from_inliers < 0:
            raise ValueError("second_look_candidates and second_look_from_inliers must be >= 0")
        if self.second_look_align_m < 0 or self.second_look_align_deg < 0:
            raise ValueError("second_look_align_m and second_look_align_deg must be >= 0")
        if self.second_look_prior_gate_m <= 0:
            raise ValueError(f"second_look_prior_gate_m must be > 0, got {self.second_look_prior_gate_m}")
        if not 0.0 <= self.second_look_max_see_through <= 1.0:
            raise ValueError(f"second_look_max_see_through must be in [0, 1] (1 = off), got "
                             f"{self.second_look_max_see_through}")
        if not -1 <= self.gl_rerank_min_similarity <= 1:
            raise ValueError("gl_rerank_min_similarity must be in [-1, 1]")
        if self.repeat_within_s < 0 or self.repeat_within_m < 0 or not 0 < self.repeat_deg <= 180:
            raise ValueError("repeat_within_s and repeat_within_m must be >= 0 (0 = off) and repeat_deg in (0, 180]")
        if self.prior_gate_sigmas < 0:
            raise ValueError("prior_gate_sigmas must be >= 0 (0 = off)")
        if self.prior_gate_rate_fused_mps < 0 or self.prior_gate_drift_fused < 0 or self.prior_gate_fused_m <= 0:
            raise ValueError("prior_gate_rate_fused_mps, prior_gate_drift_fused >= 0, prior_gate_fused_m > 0 required")
        if self.prior_gate_m <= 0 or self.prior_gate_rate_mps < 0 or not (0 < self.prior_gate_deg <= 180):
            raise ValueError("prior_gate_m > 0, prior_gate_rate_mps >= 0 and prior_gate_deg in (0, 180] required")
