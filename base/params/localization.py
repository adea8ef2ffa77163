"""Parameters of localization: depth lookup, PnP, joint refinement, GL/LL, their checks and the state
machine, one section each (config `localization`; the algorithms are `pipelines.depth_lookup`,
`pipelines.pnp` and `pipelines.localization`).

Each field is declared once with `setting` (`base/settings.py`); a range of (-inf, inf) marks a
setting whose value was never bounded (any finite number is taken as given).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

from litevloc.base.settings import Settings, section, setting

PnpMethod = Literal["p3p", "ap3p", "sqpnp", "epnp", "usac_magsac"]

_ANY = -math.inf  # `low` of a number without bounds: declared, every finite value allowed


@dataclass(frozen=True)
class DepthLookupParams(Settings):
    """Validity gates for the live depth at keypoints (metres)."""

    min_depth: float = setting(0.1, "live depth nearer than this is invalid at a keypoint", unit="m", low=0)
    max_depth: float = setting(
        10.0, "live depth farther than this is invalid at a keypoint (above min_depth)", unit="m", low=0,
        low_open=True)
    abs_tol: float = setting(
        0.03, "a keypoint's depth must agree with its neighbours' within abs_tol + rel_tol x depth: the constant part",
        unit="m", low=0)
    rel_tol: float = setting(
        0.03, "a keypoint's depth must agree with its neighbours' within abs_tol + rel_tol x depth: the part per metre "
        "of depth", unit="m/m", low=0)

    def check_relations(self) -> None:
        if not self.min_depth < self.max_depth:
            raise ValueError(f"need min_depth < max_depth, got {self.min_depth}, {self.max_depth}")


@dataclass(frozen=True)
class PnpParams(Settings):
    """RANSAC settings and acceptance gates of a PnP pose (defaults follow the published system)."""

    method: PnpMethod = setting("ap3p", "OpenCV minimal solver inside the PnP RANSAC")
    reprojection_px: float = setting(
        3.0, "PnP RANSAC inlier threshold of a correspondence's reprojection error", unit="px", low=0, low_open=True)
    iterations: int = setting(1000, "PnP RANSAC iterations at most", low=1)
    confidence: float = setting(0.9999, "PnP RANSAC confidence", low=0, high=1, low_open=True, high_open=True)
    refine_lm: bool = setting(True, "a PnP pose is refined by Levenberg-Marquardt on its RANSAC inliers")
    min_inliers: int = setting(40, "a PnP pose needs at least this many inliers", low=4)
    min_inlier_ratio: float = setting(0.2, "a PnP pose needs at least this share of its matches as inliers", low=0,
                                      high=1)
    max_median_reprojection_px: float = setting(
        2.0, "a PnP pose needs a median inlier reprojection error of at most this (inf, set in code: no such "
        "gate)", unit="px",
        low=_ANY, off=math.inf)
    seed: int = setting(0, "seed of the PnP RANSAC (results are reproducible)", low=_ANY)
    min_sigma_trans_m: float = setting(0.01, "smallest translation sigma of a PnP pose's covariance", unit="m",
                                       low=_ANY)
    min_sigma_rot_rad: float = setting(
        math.radians(0.5), "smallest rotation sigma of a PnP pose's covariance", unit="rad", low=_ANY)


@dataclass(frozen=True)
class RefineParams(Settings):
    """Joint multi-keyframe refinement and its acceptance (pixels, metres, degrees)."""

    max_keyframes: int = setting(3, "keyframes in the joint refinement, the PnP keyframe included", low=1)
    min_keyframes: int = setting(
        2, "keyframes that must each be consistent with the joint pose (at most max_keyframes)", low=1)
    min_keyframe_inliers: int = setting(
        15, "inliers under the joint pose for a keyframe to count as consistent with it", low=1)
    inlier_px: float = setting(
        3.0, "a correspondence is an inlier of the joint pose within this reprojection error (raw pixels)", unit="px",
        low=0, low_open=True)
    gate_px: float = setting(
        8.0, "a correspondence enters the joint solve if within this of the initial pose (at least inlier_px)",
        unit="px", low=0, low_open=True)
    loss: Literal["cauchy", "huber", "soft_l1"] = setting("cauchy", "robust loss of the joint solve")
    loss_scale: float = setting(2.0, "scale of the joint solve's robust loss (whitened units, sigmas)", low=0,
                                low_open=True)
    keypoint_sigma_px: float = setting(
        1.0, "keypoint position noise in the joint solve (1 sigma)", unit="px", low=0, low_open=True)
    depth_sigma_a: float = setting(
        0.0015, "depth noise sigma_z = a z^2 + b of the joint solve: the quadratic coefficient a", unit="1/m", low=0)
    depth_sigma_b: float = setting(
        0.002, "depth noise sigma_z = a z^2 + b of the joint solve: the constant b", unit="m", low=0)
    map_depth: bool = setting(
        True, "the joint solve uses the map's depth at keyframe keypoints: 3D residuals instead of reprojections "
        "where the map has depth")
    max_shift_m: float = setting(
        0.25, "the joint pose may move at most this far from the initial pose", unit="m", low=0, low_open=True)
    max_shift_deg: float = setting(
        5.0, "the joint pose may turn at most this far from the initial pose", unit="deg", low=0, low_open=True)
    sigma_sys_t_m: float = setting(
        0.0, "joint pose covariance: systematic translation error, constant part", unit="m", low=0)
    sigma_sys_r_deg: float = setting(
        0.0, "joint pose covariance: systematic rotation error, constant part", unit="deg", low=0)
    sigma_sys_t_per_rad: float = setting(
        0.083, "joint pose covariance: systematic translation error per radian between live view and keyframes",
        unit="m/rad", low=0)
    sigma_sys_r_per_rad: float = setting(
        0.0334, "joint pose covariance: systematic rotation error per radian between live view and keyframes",
        unit="rad/rad", low=0)
    sigma_sys_t_per_m: float = setting(
        0.022, "joint pose covariance: systematic translation error per metre from the keyframes", unit="m/m", low=0)
    sigma_sys_r_deg_per_m: float = setting(
        0.92, "joint pose covariance: systematic rotation error per metre from the keyframes", unit="deg/m", low=0)
    min_sigma_t_m: float = setting(0.002, "smallest translation sigma of the joint pose's covariance", unit="m", low=0)
    min_sigma_r_deg: float = setting(0.05, "smallest rotation sigma of the joint pose's covariance", unit="deg", low=0)
    max_nfev: int = setting(30, "function evaluations of the joint least-squares solve at most", low=1)
    extra_matching: Literal["guided", "model"] = setting(
        "guided", "matching of the joint solve's extra keyframes: \"guided\" by projecting with the initial pose "
        "(~1 ms), \"model\" by the matcher (~100 ms)")
    guided_radius_px: float = setting(
        8.0, "guided matching of the extra keyframes: search radius around the projected point", unit="px", low=0,
        low_open=True)
    guided_global_mutual: bool = setting(
        True, "guided matching of the extra keyframes: each pair must also be mutual nearest neighbours over all "
        "keypoints")
    guided_min_similarity: float = setting(
        0.6, "guided matching of the extra keyframes: smallest descriptor similarity of a pair (cosine)", low=-1,
        high=1)

    def check_relations(self) -> None:
        if not self.min_keyframes <= self.max_keyframes:
            raise ValueError(f"need min_keyframes <= max_keyframes, got {self.min_keyframes}, {self.max_keyframes}")
        if self.gate_px < self.inlier_px:
            raise ValueError(f"need gate_px >= inlier_px, got {self.gate_px}, {self.inlier_px}")


@dataclass(frozen=True)
class GlobalSearchParams(Settings):
    """Global localization (GL): its VPR candidates, their order, its time budget and its provisional poses."""

    top_k: int = setting(10, "keyframes retrieved by VPR and verified per GL query, best first", low=1)
    time_budget_ms: float = setting(
        0.0, "GL's time budget per query: a next candidate is tried only while it fits (0 = no budget)", unit="ms",
        low=0)
    rerank: bool = setting(
        True, "GL tries its candidates in the order of their mutual-nearest-neighbour count with the live frame")
    rerank_min_similarity: float = setting(
        0.7, "smallest descriptor similarity of a mutual nearest neighbour counted by GL's re-ranking (cosine)",
        low=-1, high=1)
    rerank_depth: int = setting(
        30, "VPR shortlist GL's re-ranking orders, its first top_k verified (0 = top_k)", low=0)
    lost_cost_ratio: float = setting(
        2.0, "once tracked, a GL query may cost this many times the median LL query (0 = no bound)", low=0)
    vote_min_inliers: int = setting(
        60, "a GL pose with this many inliers that no second keyframe sees is a provisional vote (0 = off)", low=0)
    check_prior_place: bool = setting(
        True, "a GL pose outside a fused prior's gate gives way to a pose LL verifies at the prior's place "
        "(repeating places)")


@dataclass(frozen=True)
class LocalSearchParams(Settings):
    """Local localization (LL): its candidates around the prior, its matching and when tracking is lost."""

    candidate_radius_m: float = setting(
        3.0, "LL candidates are keyframes within this distance of the prior", unit="m", low=0, low_open=True)
    max_view_angle_deg: float = setting(
        90.0, "LL candidates are keyframes looking within this angle of the prior", unit="deg", low=0, high=180,
        low_open=True)
    max_candidates: int = setting(
        3, "LL candidates chosen by place descriptor per query (then the nearest, where they leave it out)", low=1)
    trigger_distance_m: float = setting(
        7.5, "a prior farther than this from every keyframe sends the query to GL", unit="m", low=_ANY)
    guided_min_matches: int = setting(
        60, "LL with a fresh prior: guided matches stand in for the matcher's when at least this many (0 = off)",
        low=0)
    guided_global_mutual: bool = setting(
        False, "LL's guided matches (fresh prior) must also be mutual nearest neighbours over all keypoints (off: the "
        "best pair within refine.guided_radius_px; the prior gate and the joint refinement still check the pose; "
        "the second look keeps the rule)")
    failures_before_lost: int = setting(
        3, "consecutive LL failures that make the state LOST (the next query runs GL)", low=1)


@dataclass(frozen=True)
class VerifyParams(Settings):
    """A candidate keyframe's verification by PnP: what it needs and where the pose may lie."""

    min_matches: int = setting(20, "matches a candidate keyframe needs before its PnP", low=_ANY)
    max_distance_to_node_m: float = setting(
        5.0, "a verified pose must lie this close to its keyframe", unit="m", low=_ANY)
    map_depth: bool = setting(
        False, "verification and refinement use the map's depth at keyframe keypoints besides the live depth "
        "(off: it verifies aliased places)")


@dataclass(frozen=True)
class ConfirmParams(Settings):
    """Confirmation of a pose by the joint refinement's second keyframe, and when a fresh prior stands in for it."""

    gl: bool = setting(True, "a GL pose must explain matches with a second keyframe besides its own")
    gl_single_distinct_ratio: float = setting(
        2.0, "a GL pose no second keyframe confirms but whose own keyframe explains global_search.vote_min_inliers "
        "matches is accepted when no candidate at another place has >= 1/this of its PnP inliers (0 = off)",
        low=1, off=0)
    ll: bool = setting(
        True, "an LL pose must explain matches with a second keyframe besides its own (unless it lies close to a "
        "fresh prior)")
    skip_within_m: float = setting(
        0.2, "an LL pose this close to a fresh prior needs no second keyframe", unit="m", low=_ANY)
    skip_within_deg: float = setting(
        5.0, "an LL pose turned this little from a fresh prior needs no second keyframe", unit="deg", low=_ANY)
    skip_max_age_s: float = setting(
        0.5, "a prior counts as fresh for the confirmation while its gate has grown no more than prior_gate.rate_mps "
        "x this", unit="s", low=_ANY)


@dataclass(frozen=True)
class SupportParams(Settings):
    """The support check of a GL pose: the height its inliers span, and how many lie on floor and ceiling."""

    min_height_m: float = setting(
        0.15, "a GL candidate whose inliers span less height than this rests on floor or ceiling: refused (0 = off)",
        unit="m", low=0)
    min_off_layer_inliers: int = setting(
        8, "a GL candidate needs this many inliers off its two densest horizontal layers (floor and ceiling, each "
        "10 cm thick); fewer: it rests on floor and ceiling tiles only and is refused (0 = off)", low=0)
    min_off_plane_inliers: int = setting(
        0, "a GL candidate needs this many inliers farther than 5 cm from the plane holding most of them (any "
        "orientation); fewer: it rests on one surface, whose repeating texture (bricks, tiles) verifies at its other "
        "copies too, and is refused (0 = off)", low=0)


@dataclass(frozen=True)
class PriorGateParams(Settings):
    """The prior gate: how far a pose may lie from the prior it was verified from (metres, degrees)."""

    radius_m: float = setting(
        0.75, "an LL pose must lie this close to a last-VLoc-pose prior, before the gate's growth", unit="m", low=0,
        low_open=True)
    rate_mps: float = setting(
        1.5, "a last-VLoc-pose prior's gate grows at this rate per second of the prior's age", unit="m/s", low=0)
    deg: float = setting(30.0, "a pose must lie within this rotation of its prior", unit="deg", low=0, high=180,
                         low_open=True)
    rate_fused_mps: float = setting(
        0.1, "a fused prior's gate grows at this rate per second since the last fix (odometry drift)", unit="m/s",
        low=0)
    drift_fused: float = setting(
        0.2, "a fused prior's gate grows by at most this fraction of the odometry's path since the last fix (at rest: "
        "none)", unit="m/m", low=0)
    fused_m: float = setting(0.25, "a fused prior's gate starts from this radius", unit="m", low=0, low_open=True)
    sigmas: float = setting(
        3.0, "with fusion's covariance, a fused prior's gate toward a pose is at most fused_m + this many sigmas "
        "(0 = off)", low=0)


@dataclass(frozen=True)
class RepeatParams(Settings):
    """The hold: a pose its prior cannot confirm waits for a later frame that repeats it."""

    within_s: float = setting(
        5.0, "a pose outside a fused prior's gate (or with a stale prior) waits this long for a repeat (0 = off)",
        unit="s", low=0)
    within_m: float = setting(
        0.1, "a held pose may wait any time while the prior moved less than this since it (a robot at rest, slow GL)",
        unit="m", low=0)
    deg: float = setting(
        5.0, "a held pose is repeated by a later one that agrees with it within this rotation", unit="deg", low=0,
        high=180, low_open=True)


@dataclass(frozen=True)
class PassesParams(Settings):
    """The later verification passes of a refused query, on the same features and matches."""

    map_depth: bool = setting(
        True, "a query that live depth cannot verify is verified again with the map's depth (verify.map_depth for "
        "that pass alone)")
    map_depth_distinct_ratio: float = setting(
        2.0, "the map-depth pass's GL refuses a pose another place verifies with >= 1/this of its inliers "
        "(0 = distinctiveness.ratio)", low=1, off=0)
    pooled_min_inliers: int = setting(
        20, "a candidate with this many PnP inliers (< pnp.min_inliers) passes if its joint keyframes reach "
        "pnp.min_inliers (0 = off)", low=4, off=0)


@dataclass(frozen=True)
class DistinctivenessParams(Settings):
    """The distinctiveness check of a GL pose without a fresh prior: does another place verify nearly as well?"""

    ratio: float = setting(
        0.0, "GL refuses a pose if a candidate at another pose has >= 1/this of its PnP inliers (0 = off)", low=1,
        off=0)
    apart_m: float = setting(
        0.3, "candidate poses farther apart than this are different places for the distinctiveness check", unit="m",
        low=0, low_open=True)
    apart_deg: float = setting(
        10.0, "candidate poses turned further apart than this are different places for the distinctiveness check",
        unit="deg", low=0, high=180, low_open=True)
    max_rivals: int = setting(
        3, "candidates verified after the accepted one for the distinctiveness check at most (those with >= 1/ratio "
        "of its re-ranking count)", low=0)
    stronger_rival: bool = setting(
        True, "with the ratio test off, GL still refuses a pose when a candidate verified before it at another place "
        "has at least as many PnP inliers")
    screen: bool = setting(
        True, "the distinctiveness check skips the later candidates whose PnP on the re-ranking's matches (no model "
        "run) agrees with the pose")


@dataclass(frozen=True)
class SecondLookParams(Settings):
    """The full-resolution second look at a query every pass refused (its models: models.second_look_*)."""

    candidates: int = setting(
        2, "refused candidates verified again at models.second_look_size when GL refused a query (0 = off)", low=0)
    local: bool = setting(
        True, "LL gets a second look at a refused query, keeping tracking where the first look loses it (its poses "
        "are only as good as the prior's gate)")
    from_inliers: int = setting(
        10, "only candidates whose first look found at least this many PnP inliers get a second look", low=0)
    precheck_min_inliers: int = setting(
        0, "a candidate is matched at full resolution only if the mutual nearest neighbours of its full-resolution "
        "features reach this many PnP inliers (no model run; 0 = off: on 7-Scenes every look it checked passed, so "
        "it only added ~0.1 CPU-s per candidate)", low=0)
    precheck_min_similarity: float = setting(
        0.5, "the pre-check's mutual nearest neighbours need at least this descriptor similarity (cosine)", low=-1,
        high=1)
    stay: bool = setting(
        False, "after an LL query that only the second look accepted, the next LL query with a fresh prior runs the "
        "matcher model in its first look only for the keyframes that accepted that one (guided matches for all) "
        "before its second look; false: the first look runs the model for every candidate")
    prior_gate_m: float = setting(
        0.25, "LL's second look: its pose must lie this close to a last-VLoc-pose prior (for prior_gate.radius_m; "
        "the gate's growth adds)", unit="m", low=0, low_open=True)


@dataclass(frozen=True)
class SeeThroughParams(Settings):
    """The see-through check of a second-look pose: the map's points against the live depth."""

    max_share: float = setting(
        0.3, "a second-look pose putting more than this share of its keyframes' map points in view in front of the "
        "live depth is refused (1 = off)", low=0, high=1)
    align_m: float = setting(
        0.3, "a second-look pose over max_share is moved onto the live depth if the move is at most this far "
        "(0 = never)", unit="m", low=0)
    align_deg: float = setting(
        6.0, "a second-look pose over max_share is moved onto the live depth if the move turns it at most this much",
        unit="deg", low=0)


@dataclass(frozen=True)
class LocalizationParams(Settings):
    """Parameters of GL, LL, their checks and the state machine, one section each (metres, degrees)."""

    global_search: GlobalSearchParams = section(
        GlobalSearchParams, "global localization: VPR candidates, their order, the time budget, provisional poses")
    local_search: LocalSearchParams = section(
        LocalSearchParams, "local localization: candidates around the prior, guided matching, when tracking is lost")
    verify: VerifyParams = section(
        VerifyParams, "a candidate's verification by PnP: matches needed, distance to its keyframe, map depth")
    pnp: PnpParams = section(PnpParams, "PnP + RANSAC of live keypoints (with live depth) against a keyframe")
    depth: DepthLookupParams = section(DepthLookupParams, "validity gates of the live depth at keypoints")
    refine: RefineParams = section(
        RefineParams, "joint multi-keyframe refinement: a pose's confirmation by its keyframe's covisible neighbours")
    confirm: ConfirmParams = section(
        ConfirmParams, "which poses need a second keyframe, and when a fresh prior stands in for it")
    support: SupportParams = section(SupportParams, "the support check: GL poses resting on one horizontal plane")
    distinctiveness: DistinctivenessParams = section(
        DistinctivenessParams, "the distinctiveness check: a GL pose is refused when another place verifies with "
        "nearly its inliers")
    prior_gate: PriorGateParams = section(PriorGateParams, "the prior gate around the prior a pose was verified from")
    repeat: RepeatParams = section(
        RepeatParams, "the hold of a pose its prior cannot confirm, until a later frame repeats it")
    passes: PassesParams = section(
        PassesParams, "the later verification passes of a refused query (map depth, pooled weak candidates)")
    second_look: SecondLookParams = section(SecondLookParams, "the full-resolution second look at a refused query")
    see_through: SeeThroughParams = section(
        SeeThroughParams, "the see-through check of a second-look pose against the live depth")
