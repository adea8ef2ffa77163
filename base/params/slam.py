"""Parameters of the mapping pass's pose-graph SLAM (config section `slam`, used by
`litevloc.pipelines.slam` when `litevloc map build --poses slam` poses a recording itself).

Keyframes are spaced by the mapping pre-filter's motion thresholds (`mapping.keyframes`)
times `slam.keyframe_step_scale` (the rotation step also times `slam.keyframe_rotation_scale`),
and every map keyframe is a SLAM keyframe; loop verification uses the localizer's own
geometry (`localization.pnp`, `localization.refine`, `localization.depth`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from litevloc.base.params.localization import PnpParams
from litevloc.base.settings import Settings, section, setting


@dataclass(frozen=True)
class SlamOdometryParams(Settings):
    """The robot's odometry as pose-graph edges: noise model and fault checks (metres, degrees, seconds)."""

    sigma_m_per_m: float = setting(
        0.02, "translation noise of an odometry edge per metre travelled, per axis (fraction of the distance)",
        unit="m/m", low=0)
    sigma_floor_m: float = setting(
        0.002, "translation noise of an odometry edge however short it is, per axis", unit="m", low=0, low_open=True)
    sigma_deg_per_m: float = setting(
        1.5, "rotation noise of an odometry edge per metre travelled, per axis", unit="deg/m", low=0)
    sigma_deg_per_deg: float = setting(
        0.01, "rotation noise of an odometry edge per degree turned, per axis (fraction of the angle)", unit="deg/deg",
        low=0)
    sigma_floor_deg: float = setting(
        0.1, "rotation noise of an odometry edge however short it is, per axis", unit="deg", low=0, low_open=True)
    max_gap_s: float = setting(
        0.5, "a silence between odometry samples longer than this splits the odometry: no edge spans it", unit="s",
        low=0, low_open=True)
    max_speed_mps: float = setting(
        5.0, "an odometry step faster than this is a jump (a reset or a fault) and splits the odometry", unit="m/s",
        low=0, low_open=True)
    max_turn_dps: float = setting(
        720.0, "an odometry step turning faster than this is a jump (a reset or a fault) and splits the odometry",
        unit="deg/s", low=0, low_open=True)


@dataclass(frozen=True)
class KeypointAlignmentParams(Settings):
    """A visual edge's matched keypoints moved onto the same surface point (`pipelines.keypoint_alignment`):
    the source patch warped by its surface plane, the target position refined by Lucas-Kanade."""

    enabled: bool = setting(
        True, "align the target keypoints of a visual edge before its joint refinement (False: the detector's "
        "keypoints)")
    patch_radius_px: int = setting(5, "half size of the aligned patch (the patch is 2r+1 square)", unit="px", low=1)
    normal_radius_px: int = setting(4, "half size of the depth window the surface plane is fitted in", unit="px", low=1)
    max_plane_rms: float = setting(
        0.01, "a plane fit with an RMS residual above this fraction of the depth is a depth edge (no alignment)", low=0,
        low_open=True)
    iterations: int = setting(6, "Lucas-Kanade iterations (translation only)", low=1)
    max_shift_px: float = setting(
        3.0, "an alignment moving a keypoint farther than this failed (the keypoint stays as detected)", unit="px",
        low=0, low_open=True)
    min_ncc: float = setting(
        0.8, "an alignment whose aligned patches correlate less than this failed (zero-mean NCC)", low=-1, high=1)
    min_gradient: float = setting(
        0.3, "an alignment whose patch has less gradient than this in its weaker direction failed (per pixel, RMS)",
        unit="grey levels", low=0, low_open=True)


@dataclass(frozen=True)
class SlamVisualParams(Settings):
    """Visual edges between nearby keyframes, and visual odometry where the odometry is missing."""

    neighbours: int = setting(
        2, "visual edges from each keyframe to this many previous keyframes (matched with models.vo_matcher)", low=1)
    pnp: PnpParams = section(
        lambda: PnpParams(min_inliers=25, min_inlier_ratio=0.0, max_median_reprojection_px=2.0,
                          min_sigma_trans_m=0.003, min_sigma_rot_rad=float(np.radians(0.15))),
        "PnP gates of a visual edge (keyframe points lifted with its depth); min_sigma_* floor the edge's noise")
    guided_radius_px: float = setting(
        20.0, "radius of guided matching: keyframe points projected with the predicted motion (matcher if too few)",
        unit="px", low=0, low_open=True)
    guided_min_similarity: float = setting(0.6, "cosine similarity a guided match needs", low=-1, high=1)
    guided_only: bool = setting(
        True, "with an odometry prediction, a visual edge uses guided matches only (no matcher: it aliases repeated "
        "textures)")
    max_disagreement_sigma: float = setting(
        8.0, "edges into a keyframe agree within this many sigmas; the largest agreeing set is kept (dropped "
        "odometry: a fault)", low=0, low_open=True)
    skip_edge_ties: bool = setting(
        False, "odometry-vision ties broken by the next keyframe's skip edge (fixes a slow wheel slip; periodic "
        "textures fool it)")
    track_every: int = setting(
        2, "without odometry, every Nth camera frame is tracked against the last keyframe (1 = every frame)", low=1)
    track_min_inliers: int = setting(
        60, "without odometry, a tracked frame with fewer PnP inliers than this becomes a keyframe", low=-math.inf)
    align: KeypointAlignmentParams = section(
        KeypointAlignmentParams, "matched keypoints moved onto the same surface point before the edge's refinement")

    def check_relations(self) -> None:
        if self.track_min_inliers < self.pnp.min_inliers:
            raise ValueError("slam.visual.track_min_inliers must be >= slam.visual.pnp.min_inliers")


@dataclass(frozen=True)
class SlamLoopParams(Settings):
    """Loop closures: place-recognition candidates, bounded verification, robust factors."""

    exclude_recent: int = setting(
        8, "candidates are older than this many keyframes (the recent ones are linked by visual edges)", low=1)
    top_k: int = setting(3, "place-recognition candidates considered per keyframe (most similar first)", low=1)
    min_similarity: float = setting(
        0.5, "candidates less similar than this (cosine of the VPR descriptors) are not tried", low=-1, high=1)
    max_verifications: int = setting(
        1, "at most this many candidates are verified per keyframe (the cost bound: one matcher run each)", low=0)
    search_every: int = setting(
        2,
        "the loop search runs on every n-th keyframe only (the loop-search keyframes; candidates are such keyframes)",
        low=1)
    partner_spacing: int = setting(
        3, "a candidate within this many keyframes of a loop partner already verified for this keyframe is skipped",
        low=0)
    chain_pregate: bool = setting(
        True, "skip unmatched a candidate the chain puts beyond the chain gate's bound + "
        "localization.verify.max_distance_to_node_m")
    sigma_floor_m: float = setting(
        0.003, "a loop factor's translation noise is at least this, per axis", unit="m", low=0, low_open=True)
    sigma_floor_deg: float = setting(
        0.15, "a loop factor's rotation noise is at least this, per axis", unit="deg", low=0, low_open=True)


@dataclass(frozen=True)
class SlamGraphParams(Settings):
    """Robust optimisation of the pose graph (GTSAM graduated non-convexity over the loop factors)."""

    inlier_probability: float = setting(
        0.99,
        "a loop factor is an inlier while its whitened error is below the chi-square quantile at this probability",
        low=0, low_open=True, high=1, high_open=True)
    kept_weight: float = setting(
        0.5, "a loop factor whose final GNC weight is above this counts as kept (else rejected by the optimiser)",
        low=0, low_open=True, high=1, high_open=True)
    gate_loops: bool = setting(
        True, "gate loops before GNC: against the chain, then the largest pairwise consistent set (PCM; False: GNC "
        "alone)")
    gate_floor_m: float = setting(
        0.1,
        "a loop agrees with the chain (two loops with each other) within this plus the drift terms, in translation",
        unit="m", low=0)
    gate_floor_deg: float = setting(
        2.0, "a loop agrees with the chain (two loops with each other) within this plus the drift terms, in rotation",
        unit="deg", low=0)
    chain_drift_m_per_m: float = setting(
        0.1, "the chain's drift allowed per metre of chain path between the compared keyframes (fraction of the path)",
        unit="m/m", low=0)
    chain_drift_deg_per_m: float = setting(
        0.2, "the chain's rotation drift allowed per metre of chain path between the compared keyframes", unit="deg/m",
        low=0)
    gate_sigmas: float = setting(
        3.0, "the loop gate's bounds also grow by this many of the chain's own sigmas over the stretch (its edges' "
        "noise as a random walk)", low=0)
    visual_covariance_scale: float = setting(
        4.0, "the visual edges' covariance is multiplied by this in the optimisation (the refinement understates "
        "their error)", low=0, low_open=True)


@dataclass(frozen=True)
class SlamPlanarParams(Settings):
    """The platform's base moves on a floor (a wheeled or legged ground robot): between
    consecutive keyframes its base_link keeps its height, roll and pitch up to these sigmas."""

    enabled: bool = setting(
        False, "the base_link moves in a plane (a ground robot; off for a hand-held or flying camera)")
    sigma_height_m: float = setting(
        0.01, "height change of base_link between consecutive keyframes, one sigma (floor unevenness, gait; metres)",
        unit="m", low=0, low_open=True)
    sigma_tilt_deg: float = setting(
        0.5, "roll and pitch change of base_link between consecutive keyframes, one sigma", unit="deg", low=0,
        low_open=True)
    level_floor: bool = setting(
        False, "the whole pass is on one level floor (one storey, no ramps): base level and camera height held in the "
        "map frame")


@dataclass(frozen=True)
class SlamPlaneParams(Settings):
    """Walls as landmarks: vertical planes fitted to each keyframe's depth, one landmark per
    wall seen from several keyframes, holding the keyframes that see it to one plane."""

    enabled: bool = setting(
        True, "fit walls in each keyframe's depth and hold the keyframes that see one wall to that plane")
    max_depth_m: float = setting(
        5.0, "points farther than this are not used for planes (their depth noise grows with range squared)", unit="m",
        low=0, low_open=True)
    max_per_keyframe: int = setting(4, "at most this many planes per keyframe (the largest first)", low=1)
    ransac_iterations: int = setting(150, "RANSAC hypotheses per plane (pairs of points with the up direction)", low=1)
    inlier_m: float = setting(
        0.01, "a point lies on a plane within this plus `inlier_per_m2` times its depth squared", unit="m", low=0,
        low_open=True)
    inlier_per_m2: float = setting(
        0.004, "a point lies on a plane within inlier_m plus this times its depth squared", unit="1/m", low=0)
    min_points: int = setting(
        30, "a plane needs this many of the keyframe's depth points (`mapping.keyframes.pixel_stride` grid)", low=1)
    min_width_m: float = setting(
        1.0, "a wall plane's points span at least this along the floor", unit="m", low=0, low_open=True)
    min_height_m: float = setting(
        0.4, "a wall plane's points span at least this along up", unit="m", low=0, low_open=True)
    max_tilt_deg: float = setting(8.0, "a wall's normal is within this of horizontal", unit="deg", low=0, low_open=True)
    match_angle_deg: float = setting(
        6.0, "an observation joins a wall within this angle of its normal (and match_offset_m, match_gap_m)",
        unit="deg", low=0, low_open=True)
    match_offset_m: float = setting(
        0.15, "an observation joins a wall within this offset from its plane at the observation's centre", unit="m",
        low=0, low_open=True)
    match_gap_m: float = setting(
        0.5, "an observation joins a wall when it overlaps it along the floor or lies within this gap", unit="m", low=0)
    min_keyframes: int = setting(3, "a wall becomes a landmark when this many keyframes see it", low=1)
    sigma_normal_rad: float = setting(0.01, "one sigma of an observed plane's normal", unit="rad", low=0, low_open=True)
    sigma_offset_m: float = setting(
        0.01, "one sigma of an observed plane's distance from the camera", unit="m", low=0, low_open=True)
    outlier_error: float = setting(
        5.67,
        "observations whose factor error (half the squared whitened error) exceeds this are dropped, then solved again",
        low=0, low_open=True)


@dataclass(frozen=True)
class SlamParams(Settings):
    """The mapping pass's SLAM (see the module docstring), and external trajectories (`--poses FILE`)."""

    keyframe_step_scale: float = setting(
        1.0, "SLAM keyframes (the map's keyframe candidates) every this many mapping.keyframes steps (translation, "
        "rotation)", low=1)
    keyframe_rotation_scale: float = setting(
        1.0, "the rotation step of SLAM keyframes is a further this many times longer (a robot turning in place sees "
        "the same place)", low=1)
    odometry: SlamOdometryParams = section(SlamOdometryParams, "the robot's odometry as pose-graph edges")
    visual: SlamVisualParams = section(
        SlamVisualParams, "visual edges between nearby keyframes, and visual odometry where odometry is missing")
    loops: SlamLoopParams = section(SlamLoopParams, "loop closures: candidates, verification, robust factors")
    graph: SlamGraphParams = section(SlamGraphParams, "robust optimisation of the pose graph")
    planar: SlamPlanarParams = section(
        SlamPlanarParams, "planar motion of a ground robot's base between consecutive keyframes")
    planes: SlamPlaneParams = section(SlamPlaneParams, "walls as plane landmarks in the final optimisation")
    vo_matcher: Literal["lightglue", "lightglue-int8", "lightglue-adaptive", "mnn", "nn-ratio"] = setting(
        "mnn", "matcher of visual edges and tracking (loops use models.matcher); PnP with depth verifies its matches")
    file_max_gap_s: float = setting(
        1.0, "--poses FILE: frames in a gap of the trajectory longer than this get no pose (lost tracking)", unit="s",
        low=0, low_open=True)
