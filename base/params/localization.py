"""Parameters of localization: depth lookup, PnP, joint refinement, GL/LL and the state machine.

Re-exported by `pipelines.depth_lookup`, `pipelines.pnp`, `pipelines.localization.refine` and
`pipelines.localization.vloc` under their old names (the algorithms live there).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np

PnpMethod = Literal["p3p", "ap3p", "sqpnp", "epnp", "usac_magsac"]


@dataclass(frozen=True)
class DepthLookupParams:
    """Validity gates for depth at keypoints (metres)."""

    min_depth: float = 0.1
    max_depth: float = 10.0
    abs_tol: float = 0.03
    rel_tol: float = 0.03

    def __post_init__(self) -> None:
        if not (0 <= self.min_depth < self.max_depth):
            raise ValueError(f"need 0 <= min_depth < max_depth, got {self.min_depth}, {self.max_depth}")
        if self.abs_tol < 0 or self.rel_tol < 0:
            raise ValueError("abs_tol and rel_tol must be >= 0")


@dataclass(frozen=True)
class PnpParams:
    """RANSAC settings and acceptance gates (defaults follow the published system)."""

    method: PnpMethod = "ap3p"
    reprojection_px: float = 3.0
    iterations: int = 1000
    confidence: float = 0.9999
    refine_lm: bool = True
    # 50 -> 40 (the office preset had 40): 38 vs 26 % of 7-Scenes mapping-pass queries (map 250-499)
    # accepted; 30 accepts 43 % there but, with guided matching, poses 0.6-1.2 m off along the
    # optical axis on the office's repetitive corridor walls (40 accepts none of them)
    min_inliers: int = 40
    min_inlier_ratio: float = 0.2
    max_median_reprojection_px: float = 2.0
    seed: int = 0
    min_sigma_trans_m: float = 0.01
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

    enabled: bool = True  # False: the single-keyframe PnP pose + separate confirmation (old behaviour)
    max_keyframes: int = 3  # keyframes in the joint solve, the PnP keyframe included
    min_keyframes: int = 2  # keyframes that must each be consistent with the joint pose
    min_keyframe_inliers: int = 15  # inliers under the joint pose for a keyframe to count as consistent
    inlier_px: float = 3.0  # reprojection threshold of an inlier (raw pixels)
    gate_px: float = 8.0  # a correspondence enters the solve if within this of the initial pose
    loss: Literal["cauchy", "huber", "soft_l1"] = "cauchy"
    loss_scale: float = 2.0  # in whitened units (sigma)
    keypoint_sigma_px: float = 1.0
    depth_sigma_a: float = 0.0015  # sigma_z = a z^2 + b (m), structured-light / stereo depth noise
    depth_sigma_b: float = 0.002
    # Where the map keeps depth at a matched keyframe keypoint, the correspondence enters the
    # solve as a 3D residual (live point moved into the keyframe minus the keyframe's point,
    # whitened by both depths' noise and the keypoint noise) instead of a reprojection. Chosen on
    # the 7-Scenes mapping-pass splits (below): [5 cm, 5 deg] 25.6 / 47.2 % vs 24.8 / 35.2 %,
    # median 1.88 / 2.65 cm vs 2.13 / 3.33 cm, max 10.2 / 10.5 vs 10.4 / 23 cm.
    map_depth: bool = True
    max_shift_m: float = 0.25  # the joint pose may move at most this far from the initial pose
    max_shift_deg: float = 5.0
    # Systematic error that points and keyframes do not average out, and its growth with the
    # angle between the live view and its keyframes (metres per radian, radians per radian) and
    # with their distance from it (metres per metre, degrees per metre; see
    # pipelines.localization.refine). Fitted by maximum likelihood (`python bench/fit_covariance.py`,
    # x1.1 on translation for 95 % coverage) on two tuning splits inside the 7-Scenes mapping
    # pass (map 250-499 / queries 0:250:2 and map 0-249 / queries 250:500:2, 109 accepted poses):
    # 95.4 % / 98.2 % of their errors inside the 95 % ellipsoids. The distance terms entered
    # 2026-11-26: on the splits the error grows with the distance to the keyframes (median 0.8 cm
    # below 0.3 m, 2-3.5 cm at 0.3-1 m, 5-9 cm beyond) at view angles of ~5 deg, which the
    # angle-only model had to put into its constant and slope; with them the log-likelihood of
    # the fit is higher by 33 (translation) and 32 (rotation) for one parameter each, and the
    # constant terms fit to zero. Before: 0.008 m, 0.41 deg, 0.115 m/rad, 0.046 rad/rad, no
    # distance terms. Held-out query pass (frames 500-999, view angles median 19 deg): 100 % /
    # 95.0 % inside (was 100 / 100 %).
    sigma_sys_t_m: float = 0.0
    sigma_sys_r_deg: float = 0.0
    sigma_sys_t_per_rad: float = 0.083
    sigma_sys_r_per_rad: float = 0.0334
    sigma_sys_t_per_m: float = 0.022
    sigma_sys_r_deg_per_m: float = 0.92
    min_sigma_t_m: float = 0.002
    min_sigma_r_deg: float = 0.05
    max_nfev: int = 30
    # How the live frame is matched to the extra keyframes: "guided" projects the live points
    # with the initial pose and pairs each with the most similar keyframe keypoint within
    # guided_radius_px (mutual best, similarity >= guided_min_similarity; ~1 ms per keyframe);
    # "model" runs the configured matcher (LightGlue, ~100 ms per keyframe on 2 CPUs).
    extra_matching: Literal["guided", "model"] = "guided"
    guided_radius_px: float = 8.0
    # Also require each guided pair to be the mutual nearest neighbour over ALL keypoints of
    # both images (not just within the radius): the pose then only filters matches it did not
    # choose, so a wrong pose on a repetitive texture cannot confirm itself (office, frame 810).
    guided_global_mutual: bool = True
    guided_min_similarity: float = 0.6  # 0.75 -> 0.6: 43 -> 50 % accepted on the 7-Scenes mapping pass (0.5: no better)

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

    # Place candidates GL verifies (geometric check), best first.
    gl_top_k: int = 10
    # > 0: stop GL at the first candidate with this many inliers (refine off).
    gl_early_accept_inliers: int = 0
    # > 0: a wall-time budget (ms, whole GL query); the next candidate is tried only while the
    # time spent plus one more candidate's expected cost fits (one is always verified).
    gl_time_budget_ms: float = 0.0
    # Re-order GL candidates by their count of mutual nearest neighbours with the live frame's
    # descriptors (no model run), place-descriptor order breaking ties.
    gl_rerank: bool = True
    # Descriptor similarity (cosine) a mutual nearest neighbour needs to count in the re-ordering.
    gl_rerank_min_similarity: float = 0.7
    # Place-descriptor shortlist (nodes) that the re-ordering ranks, its first gl_top_k verified;
    # 0 = gl_top_k (the re-ordering only orders the verified candidates).
    gl_rerank_depth: int = 0
    # Once tracked, a GL query may spend at most this x the median wall time of the recent LL
    # queries (the next candidate only while it fits; one is always verified). 0 = no bound.
    lost_cost_ratio: float = 2.0
    # A GL pose must also explain matches with a second keyframe (repetitive textures fool one view).
    gl_confirm: bool = True
    # An LL pose must too, unless it lies close to a fresh prior (confirm_skip_*).
    ll_confirm: bool = True
    # PnP inliers of a GL pose that only its own keyframe confirms for it to be returned as a
    # provisional pose (a fusion vote; accepted in GLOBAL state when it agrees with the prior). 0 = off.
    gl_vote_min_inliers: int = 60
    # A GL pose whose supporting points span less than this (m, 10th-90th percentile along the
    # map's up) rests on the floor or ceiling alone, whose tiles repeat: rejected. 0 = off.
    gl_min_support_height_m: float = 0.15
    confirm_min_inliers: int = 20
    confirm_max_nodes: int = 2  # second keyframes tried for the confirmation
    # An LL pose this close to a fresh prior (age <= confirm_skip_max_age_s) needs no second
    # keyframe: whatever it could be wrong by is bounded by this distance plus the prior's error.
    confirm_skip_within_m: float = 0.2
    confirm_skip_within_deg: float = 5.0
    confirm_skip_max_age_s: float = 0.5
    # LL prior gate: an LL pose must lie within prior_gate_m + prior_gate_rate_mps * (age of the
    # prior in s) and prior_gate_deg of the prior; otherwise that candidate is rejected.
    prior_gate_m: float = 0.75
    prior_gate_rate_mps: float = 1.5
    prior_gate_deg: float = 30.0
    # A fused prior (the runtime's: odometry since the last fix, at the frame's stamp) grows
    # with the odometry's drift, not with the robot's speed: its gate grows at this rate per
    # second since the last fix (the simulator's seeded drift: 26 m over the 405 s loop lap,
    # 0.064 m/s). It may skip the second keyframe (confirm_skip_*) while its growth is at most
    # what a last-VLoc-pose prior is allowed (prior_gate_rate_mps * confirm_skip_max_age_s).
    prior_gate_rate_fused_mps: float = 0.1
    # ... and starts from this radius instead of prior_gate_m: while tracking, the fused prior is
    # centimetre-accurate, so its gate only has to hold the VLoc error and the prior's error at
    # the last fix. With 0.75 m the loop world's repetitive corridor let 99 of 679 LL poses
    # through at 0.5-0.76 m (the texture's period), one lap, simulator.
    prior_gate_fused_m: float = 0.25
    # A GL pose outside the fused prior's gate (prior_gate_fused_m + its growth, prior_gate_deg),
    # or with a prior too old to stand in for a second view (growth beyond what confirm_skip_*
    # allows: 7.5 s at the fused rate), is held, not accepted, until the GL pose of a later
    # frame, at most repeat_within_s after it, repeats it: carried over by the prior's own
    # motion between the two frames (the odometry), the two must agree within
    # prior_gate_fused_m + prior_gate_rate_fused_mps x the time between them and repeat_deg.
    # A stale prior cannot veto a wrong place (loop world: a GL pose 1.79 m off, confirmed by
    # two neighbouring keyframes, 1.68 m from a 10.7 s old prior whose gate had grown to 1.32 m;
    # two more 0.57-0.59 m off, the corridor texture's period, inside the gates of 7.5 and 13 s
    # old priors); a wrong place rarely repeats from a second viewpoint, a right one does, and a
    # prior that is itself wrong (a kidnapped robot) costs one more GL query. An LL pose with a
    # fused prior that stale is held the same way (loop: an LL pose 0.6 m off at a 12.3-12.6 s
    # old prior in 2 of 3 laps without this, in neither of 2 laps with it). Chosen on the loop
    # query laps it is reported on (labelled as tuned there). 0 = off (accepted at once).
    repeat_within_s: float = 5.0
    repeat_deg: float = 5.0
    candidate_radius_m: float = 3.0
    max_view_angle_deg: float = 90.0
    ll_max_candidates: int = 3
    # LL with a fresh prior (see confirm_skip_max_age_s) first matches each candidate by
    # projecting the live points with the prior (refine.guided_*: radius, similarity, mutual
    # nearest neighbours over all keypoints; ~5 ms); with at least this many matches they stand
    # in for the matcher's (a PnP that fails on them falls back to the matcher). 0 = off.
    # Chosen on the simulated office query pass (ground-truth prior, 158 LL queries, 1 thread):
    # LightGlue calls per LL query 1.40 -> 0.59 with 60, median error 0.81 -> 1.08 cm, max
    # 10.6 -> 19.1 cm; in the service (bench/runtime.py, same session) VLoc 2.07 -> 3.07 Hz.
    # 7-Scenes (bench/accuracy.py, held-out): within [5 cm, 5 deg] 56.6 -> 55.8 %, median
    # 3.78 -> 3.85 cm, LL latency median 310 -> 179 ms.
    ll_guided_min_matches: int = 60
    ll_failures_before_lost: int = 3
    gl_trigger_distance_m: float = 7.5  # prior farther than this from every node -> GL
    max_distance_to_node_m: float = 5.0  # an accepted pose must lie this close to its node
    min_matches: int = 20
    # Verification and refinement also use the map's depth at keyframe keypoints: PnP both ways
    # (the direction with more inliers wins), keyframe points reprojected into the live image
    # where the live keypoint has no depth. Off: it also verifies aliased places (docs/localization.md).
    verify_map_depth: bool = False
    pnp: PnpParams = field(default_factory=PnpParams)
    depth: DepthLookupParams = field(default_factory=DepthLookupParams)
    # Joint multi-keyframe refinement (`refine.py`); when enabled it replaces the separate
    # confirmation (gl_confirm / ll_confirm / confirm_* then only decide whether it must
    # find a second consistent keyframe).
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
        if self.gl_rerank_depth < 0:
            raise ValueError("gl_rerank_depth must be >= 0")
        if not -1 <= self.gl_rerank_min_similarity <= 1:
            raise ValueError("gl_rerank_min_similarity must be in [-1, 1]")
        if self.repeat_within_s < 0 or not 0 < self.repeat_deg <= 180:
            raise ValueError("repeat_within_s must be >= 0 (0 = off) and repeat_deg in (0, 180]")
        if self.prior_gate_rate_fused_mps < 0 or self.prior_gate_fused_m <= 0:
            raise ValueError("prior_gate_rate_fused_mps must be >= 0 and prior_gate_fused_m > 0")
        if self.prior_gate_m <= 0 or self.prior_gate_rate_mps < 0 or not (0 < self.prior_gate_deg <= 180):
            raise ValueError("prior_gate_m > 0, prior_gate_rate_mps >= 0 and prior_gate_deg in (0, 180] required")
