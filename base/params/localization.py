"""Parameters of localization: depth lookup, PnP, joint refinement, GL/LL, their checks and the state
machine, one section each (config `localization`; the algorithms are `pipelines.depth_lookup`,
`pipelines.pnp` and `pipelines.localization`).
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
    # a pose needs at least this share of the matches as inliers
    min_inlier_ratio: float = 0.2
    # a pose needs a median inlier reprojection error of at most this (pixels)
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
    # the joint pose may turn at most this far from the initial pose (degrees)
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
class GlobalSearchParams:
    """Global localization (GL): its VPR candidates, their order, its time budget and its provisional poses."""

    # keyframes retrieved by VPR and verified per GL query, best first
    top_k: int = 10
    # GL's time budget per query (ms): a next candidate is tried only while it fits (0 = no budget)
    time_budget_ms: float = 0.0
    # GL tries its candidates in the order of their mutual-nearest-neighbour count with the live frame
    rerank: bool = True
    # smallest descriptor similarity of a mutual nearest neighbour counted by the re-ranking (cosine)
    rerank_min_similarity: float = 0.7
    # VPR shortlist the re-ranking orders, its first top_k verified (0 = top_k)
    rerank_depth: int = 0
    # once tracked, a GL query may cost this many times the median LL query (0 = no bound)
    lost_cost_ratio: float = 2.0
    # a GL pose with this many inliers that no second keyframe sees is a provisional vote (0 = off)
    vote_min_inliers: int = 60
    # a GL pose outside a fused prior's gate gives way to a pose LL verifies at the prior's place (repeating places)
    check_prior_place: bool = True

    def __post_init__(self) -> None:
        if self.top_k < 1:
            raise ValueError(f"top_k must be >= 1, got {self.top_k}")
        if self.vote_min_inliers < 0:
            raise ValueError("vote_min_inliers must be >= 0 (0 = no provisional poses)")
        if self.time_budget_ms < 0:
            raise ValueError("time_budget_ms must be >= 0 (0 = no budget)")
        if self.lost_cost_ratio < 0:
            raise ValueError("lost_cost_ratio must be >= 0 (0 = no bound)")
        if self.rerank_depth < 0:
            raise ValueError("rerank_depth must be >= 0")
        if not -1 <= self.rerank_min_similarity <= 1:
            raise ValueError("rerank_min_similarity must be in [-1, 1]")


@dataclass(frozen=True)
class LocalSearchParams:
    """Local localization (LL): its candidates around the prior, its matching and when tracking is lost."""

    # LL candidates: keyframes within this distance of the prior (m)
    candidate_radius_m: float = 3.0
    # LL candidates: keyframes looking within this angle of the prior (degrees)
    max_view_angle_deg: float = 90.0
    # LL candidates by place descriptor per query (then the nearest, where they leave it out)
    max_candidates: int = 3
    # a prior farther than this from every keyframe sends the query to GL (m)
    trigger_distance_m: float = 7.5
    # LL with a fresh prior: guided matches stand in for the matcher's when at least this many (0 = off)
    guided_min_matches: int = 60
    # consecutive LL failures that make the state LOST (the next query runs GL)
    failures_before_lost: int = 3

    def __post_init__(self) -> None:
        if self.guided_min_matches < 0:
            raise ValueError(f"guided_min_matches must be >= 0, got {self.guided_min_matches}")
        if self.max_candidates < 1 or self.failures_before_lost < 1:
            raise ValueError("max_candidates and failures_before_lost must be >= 1")
        if self.candidate_radius_m <= 0 or not (0 < self.max_view_angle_deg <= 180):
            raise ValueError("candidate_radius_m > 0 and max_view_angle_deg in (0, 180] required")


@dataclass(frozen=True)
class VerifyParams:
    """A candidate keyframe's verification by PnP: what it needs and where the pose may lie."""

    # matches a candidate needs before PnP
    min_matches: int = 20
    # an accepted pose must lie this close to its keyframe (m)
    max_distance_to_node_m: float = 5.0
    # verification and refinement also use the map's depth at keyframe keypoints (off: it verifies aliased places too)
    map_depth: bool = False


@dataclass(frozen=True)
class ConfirmParams:
    """Confirmation of a pose by the joint refinement's second keyframe, and when a fresh prior stands in for it."""

    # a GL pose must also explain matches with a second keyframe
    gl: bool = True
    # an LL pose must also explain matches with a second keyframe (unless it lies close to a fresh prior)
    ll: bool = True
    # an LL pose this close to a fresh prior needs no second keyframe (m)
    skip_within_m: float = 0.2
    # an LL pose turned this little from a fresh prior needs no second keyframe (degrees)
    skip_within_deg: float = 5.0
    # a prior is fresh while its gate has grown no more than prior_gate.rate_mps x this (s)
    skip_max_age_s: float = 0.5


@dataclass(frozen=True)
class SupportParams:
    """The support check of a GL pose: the height its inliers span."""

    # a GL candidate whose inliers span less height than this rests on floor or ceiling: refused (m; 0 = off)
    min_height_m: float = 0.15

    def __post_init__(self) -> None:
        if self.min_height_m < 0:
            raise ValueError("min_height_m must be >= 0 (0 = off)")


@dataclass(frozen=True)
class PriorGateParams:
    """The prior gate: how far a pose may lie from the prior it was verified from (metres, degrees)."""

    # an LL pose must lie this close to a last-VLoc-pose prior, before its growth (m)
    radius_m: float = 0.75
    # a last-VLoc-pose prior's gate grows at this rate per second of its age (m/s)
    rate_mps: float = 1.5
    # a pose must lie within this rotation of the prior (degrees)
    deg: float = 30.0
    # a fused prior's gate grows at this rate per second since the last fix (m/s: odometry drift)
    rate_fused_mps: float = 0.1
    # a fused prior's gate grows by at most this fraction of the odometry's path since the fix (at rest: none)
    drift_fused: float = 0.2
    # a fused prior's gate starts from this radius (m)
    fused_m: float = 0.25
    # with fusion's covariance, a fused prior's gate toward a pose is at most fused_m + this many sigmas (0 = off)
    sigmas: float = 3.0

    def __post_init__(self) -> None:
        if self.sigmas < 0:
            raise ValueError("sigmas must be >= 0 (0 = off)")
        if self.rate_fused_mps < 0 or self.drift_fused < 0 or self.fused_m <= 0:
            raise ValueError("rate_fused_mps, drift_fused >= 0, fused_m > 0 required")
        if self.radius_m <= 0 or self.rate_mps < 0 or not (0 < self.deg <= 180):
            raise ValueError("radius_m > 0, rate_mps >= 0 and deg in (0, 180] required")


@dataclass(frozen=True)
class RepeatParams:
    """The hold: a pose its prior cannot confirm waits for a later frame that repeats it."""

    # a pose outside a fused prior's gate (or with a stale prior) waits this long for a repeat (s; 0 = off)
    within_s: float = 5.0
    # a held pose may wait any time while the prior moved less than this since it (m: a robot at rest, slow GL)
    within_m: float = 0.1
    # a held pose is repeated when the two agree within this rotation (degrees)
    deg: float = 5.0

    def __post_init__(self) -> None:
        if self.within_s < 0 or self.within_m < 0 or not 0 < self.deg <= 180:
            raise ValueError("within_s and within_m must be >= 0 (0 = off) and deg in (0, 180]")


@dataclass(frozen=True)
class PassesParams:
    """The later verification passes of a refused query, on the same features and matches."""

    # a query that live depth cannot verify is verified again with the map's depth (verify.map_depth for it alone)
    map_depth: bool = True
    # the map-depth pass's GL refuses a pose another place verifies with >= 1/this of its inliers (0 = the check's)
    map_depth_distinct_ratio: float = 2.0
    # a candidate with this many PnP inliers (< pnp.min_inliers) passes if its joint keyframes reach that many (0 = off)
    pooled_min_inliers: int = 20

    def __post_init__(self) -> None:
        if self.map_depth_distinct_ratio < 0 or 0 < self.map_depth_distinct_ratio < 1:
            raise ValueError("map_depth_distinct_ratio must be 0 (distinctiveness.ratio) or >= 1")
        if self.pooled_min_inliers < 0 or 0 < self.pooled_min_inliers < 4:
            raise ValueError("pooled_min_inliers must be 0 (off) or >= 4")


@dataclass(frozen=True)
class DistinctivenessParams:
    """The distinctiveness check of a GL pose without a fresh prior: does another place verify nearly as well?"""

    # GL refuses a pose if a candidate at another pose has >= 1/this of its PnP inliers (0 = off)
    ratio: float = 0.0
    # candidate poses farther apart than this are different places for the check (m)
    apart_m: float = 0.3
    # candidate poses turned further apart than this are different places for the check (degrees)
    apart_deg: float = 10.0
    # candidates verified after the accepted one for the check at most (those with >= 1/ratio of its re-ranking count)
    max_rivals: int = 3
    # the check skips the later candidates whose PnP on the re-ranking's matches (no model run) agrees with the pose
    screen: bool = True

    def __post_init__(self) -> None:
        if self.ratio < 0 or 0 < self.ratio < 1:
            raise ValueError("ratio must be 0 (off) or >= 1")
        if self.apart_m <= 0 or not 0 < self.apart_deg <= 180 or self.max_rivals < 0:
            raise ValueError("need apart_m > 0, apart_deg in (0, 180] and max_rivals >= 0")


@dataclass(frozen=True)
class SecondLookParams:
    """The full-resolution second look at a query every pass refused (its models: models.second_look_*)."""

    # refused candidates verified again at models.second_look_size when GL refused a query (0 = off)
    candidates: int = 2
    # LL looks again too (keeps tracking where the first look loses it; its poses are only as good as the prior's gate)
    local: bool = True
    # only candidates whose first look found at least this many PnP inliers are looked at again
    from_inliers: int = 10
    # LL's look: its pose must lie this close to a last-VLoc-pose prior (m, for prior_gate.radius_m; its growth adds)
    prior_gate_m: float = 0.25

    def __post_init__(self) -> None:
        if self.candidates < 0 or self.from_inliers < 0:
            raise ValueError("candidates and from_inliers must be >= 0")
        if self.prior_gate_m <= 0:
            raise ValueError(f"prior_gate_m must be > 0, got {self.prior_gate_m}")


@dataclass(frozen=True)
class SeeThroughParams:
    """The see-through check of a second-look pose: the map's points against the live depth."""

    # a pose putting more than this share of its keyframes' map points in view in front of the live depth is refused
    max_share: float = 0.3
    # a pose over that share is moved onto the live depth if the move is at most this far (m; 0 = never)
    align_m: float = 0.3
    # a pose over that share is moved onto the live depth if the move turns it at most this much (degrees)
    align_deg: float = 6.0

    def __post_init__(self) -> None:
        if self.align_m < 0 or self.align_deg < 0:
            raise ValueError("align_m and align_deg must be >= 0")
        if not 0.0 <= self.max_share <= 1.0:
            raise ValueError(f"max_share must be in [0, 1] (1 = off), got {self.max_share}")


@dataclass(frozen=True)
class LocalizationParams:
    """Parameters of GL, LL, their checks and the state machine, one section each (metres, degrees)."""

    # global localization: VPR candidates, their order, the time budget, provisional poses
    global_search: GlobalSearchParams = field(default_factory=GlobalSearchParams)
    # local localization: candidates around the prior, guided matching, when tracking is lost
    local_search: LocalSearchParams = field(default_factory=LocalSearchParams)
    # a candidate's verification by PnP: matches needed, distance to its keyframe, map depth
    verify: VerifyParams = field(default_factory=VerifyParams)
    # PnP + RANSAC of live keypoints (with live depth) against a keyframe
    pnp: PnpParams = field(default_factory=PnpParams)
    # validity gates of the live depth at keypoints
    depth: DepthLookupParams = field(default_factory=DepthLookupParams)
    # joint multi-keyframe refinement: a pose's confirmation by its keyframe's covisible neighbours
    refine: RefineParams = field(default_factory=RefineParams)
    # which poses need a second keyframe, and when a fresh prior stands in for it
    confirm: ConfirmParams = field(default_factory=ConfirmParams)
    # the support check: GL poses resting on one horizontal plane
    support: SupportParams = field(default_factory=SupportParams)
    # the distinctiveness check: GL poses another place verifies nearly as well
    distinctiveness: DistinctivenessParams = field(default_factory=DistinctivenessParams)
    # the prior gate around the prior a pose was verified from
    prior_gate: PriorGateParams = field(default_factory=PriorGateParams)
    # the hold of a pose its prior cannot confirm, until a later frame repeats it
    repeat: RepeatParams = field(default_factory=RepeatParams)
    # the later verification passes of a refused query (map depth, pooled weak candidates)
    passes: PassesParams = field(default_factory=PassesParams)
    # the full-resolution second look at a refused query
    second_look: SecondLookParams = field(default_factory=SecondLookParams)
    # the see-through check of a second-look pose against the live depth
    see_through: SeeThroughParams = field(default_factory=SeeThroughParams)
