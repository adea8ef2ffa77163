"""Parameters of the mapping pass's pose-graph SLAM (config section `slam`, used by
`litevloc.pipelines.slam` when `litevloc map build --poses slam` poses a recording itself).

Keyframes are spaced by the mapping pre-filter's motion thresholds (`mapping.keyframes`)
times `slam.keyframe_step_scale` (the rotation step also times `slam.keyframe_rotation_scale`),
and every map keyframe is a SLAM keyframe; loop verification uses the localizer's own
geometry (`localization.pnp`, `localization.refine`, `localization.depth`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from litevloc.base.params.localization import PnpParams


@dataclass(frozen=True)
class SlamOdometryParams:
    """The robot's odometry as pose-graph edges: noise model and fault checks (metres, degrees, seconds)."""

    # translation noise of an odometry edge per metre travelled, per axis (fraction of the distance)
    sigma_m_per_m: float = 0.02
    # translation noise of an odometry edge however short it is, per axis (metres)
    sigma_floor_m: float = 0.002
    # rotation noise of an odometry edge per metre travelled, per axis (degrees per metre)
    sigma_deg_per_m: float = 1.5
    # rotation noise of an odometry edge per degree turned, per axis (fraction of the angle)
    sigma_deg_per_deg: float = 0.01
    # rotation noise of an odometry edge however short it is, per axis (degrees)
    sigma_floor_deg: float = 0.1
    # a silence between odometry samples longer than this splits the odometry: no edge spans it (seconds)
    max_gap_s: float = 0.5
    # an odometry step faster than this is a jump (a reset or a fault) and splits the odometry (m/s)
    max_speed_mps: float = 5.0
    # an odometry step turning faster than this is a jump too (degrees per second)
    max_turn_dps: float = 720.0

    def __post_init__(self) -> None:
        for name in ("sigma_m_per_m", "sigma_floor_m", "sigma_deg_per_m", "sigma_deg_per_deg", "sigma_floor_deg"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise ValueError(f"slam.odometry.{name} must be a finite number >= 0, got {v}")
        if self.sigma_floor_m <= 0 or self.sigma_floor_deg <= 0:
            raise ValueError("slam.odometry.sigma_floor_m and sigma_floor_deg must be > 0")
        for name in ("max_gap_s", "max_speed_mps", "max_turn_dps"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"slam.odometry.{name} must be a finite number > 0, got {v}")


@dataclass(frozen=True)
class KeypointAlignmentParams:
    """A visual edge's matched keypoints moved onto the same surface point (`pipelines.keypoint_alignment`):
    the source patch warped by its surface plane, the target position refined by Lucas-Kanade."""

    # align the target keypoints of a visual edge before its joint refinement (False: the detector's keypoints)
    enabled: bool = True
    # half size of the aligned patch (pixels; the patch is 2r+1 square)
    patch_radius_px: int = 5
    # half size of the depth window the surface plane is fitted in (pixels)
    normal_radius_px: int = 4
    # a plane fit with an RMS residual above this fraction of the depth is a depth edge (no alignment)
    max_plane_rms: float = 0.01
    # Lucas-Kanade iterations (translation only)
    iterations: int = 6
    # an alignment moving a keypoint farther than this failed (pixels; the keypoint stays as detected)
    max_shift_px: float = 3.0
    # ... as does one whose aligned patches correlate less than this (zero-mean NCC)
    min_ncc: float = 0.8
    # ... or whose patch has less gradient than this in its weaker direction (grey levels per pixel, RMS)
    min_gradient: float = 0.3

    def __post_init__(self) -> None:
        if self.patch_radius_px < 1 or self.normal_radius_px < 1 or self.iterations < 1:
            raise ValueError("slam.visual.align: patch_radius_px, normal_radius_px and iterations must be >= 1")
        for name in ("max_plane_rms", "max_shift_px", "min_gradient"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"slam.visual.align.{name} must be a finite number > 0, got {v}")
        if not -1 <= self.min_ncc <= 1:
            raise ValueError(f"slam.visual.align.min_ncc must be in [-1, 1], got {self.min_ncc}")


@dataclass(frozen=True)
class SlamVisualParams:
    """Visual edges between nearby keyframes, and visual odometry where the odometry is missing."""

    # visual edges from each keyframe to this many previous keyframes (matched with models.vo_matcher)
    neighbours: int = 2
    # PnP gates of a visual edge (keyframe points lifted with its depth); min_sigma_* floor the edge's noise
    pnp: PnpParams = field(default_factory=lambda: PnpParams(
        min_inliers=25, min_inlier_ratio=0.0, max_median_reprojection_px=2.0, min_sigma_trans_m=0.003,
        min_sigma_rot_rad=float(np.radians(0.15))))
    # radius of guided matching: keyframe points projected with the predicted motion (pixels; matcher if too few)
    guided_radius_px: float = 20.0
    # cosine similarity a guided match needs
    guided_min_similarity: float = 0.6
    # with an odometry prediction, a visual edge uses guided matches only (no matcher: it aliases repeated textures)
    guided_only: bool = True
    # edges into a keyframe agree within this many sigmas; the largest agreeing set is kept (dropped odometry: a fault)
    max_disagreement_sigma: float = 8.0
    # odometry-vision ties broken by the next keyframe's skip edge (fixes a slow wheel slip; periodic textures fool it)
    skip_edge_ties: bool = False
    # without odometry, every Nth camera frame is tracked against the last keyframe (1 = every frame)
    track_every: int = 2
    # without odometry, a tracked frame with fewer PnP inliers than this becomes a keyframe
    track_min_inliers: int = 60
    # matched keypoints moved onto the same surface point before the edge's refinement
    align: KeypointAlignmentParams = field(default_factory=KeypointAlignmentParams)

    def __post_init__(self) -> None:
        if self.neighbours < 1 or self.track_every < 1:
            raise ValueError("slam.visual.neighbours and slam.visual.track_every must be >= 1")
        if not (self.guided_radius_px > 0 and -1 <= self.guided_min_similarity <= 1):
            raise ValueError("slam.visual.guided_radius_px must be > 0, guided_min_similarity in [-1, 1]")
        if not (np.isfinite(self.max_disagreement_sigma) and self.max_disagreement_sigma > 0):
            raise ValueError("slam.visual.max_disagreement_sigma must be a finite number > 0")
        if self.track_min_inliers < self.pnp.min_inliers:
            raise ValueError("slam.visual.track_min_inliers must be >= slam.visual.pnp.min_inliers")


@dataclass(frozen=True)
class SlamLoopParams:
    """Loop closures: place-recognition candidates, bounded verification, robust factors."""

    # candidates are older than this many keyframes (the recent ones are linked by visual edges)
    exclude_recent: int = 8
    # place-recognition candidates considered per keyframe (most similar first)
    top_k: int = 3
    # candidates less similar than this (cosine of the VPR descriptors) are not tried
    min_similarity: float = 0.5
    # at most this many candidates are verified per keyframe (the cost bound: one matcher run each)
    max_verifications: int = 1
    # the loop search runs on every n-th keyframe only (the loop-search keyframes; candidates are such keyframes)
    search_every: int = 2
    # a candidate within this many keyframes of a loop partner already verified for this keyframe is skipped
    partner_spacing: int = 3
    # skip unmatched a candidate the chain puts beyond its gate's bound + localization.verify.max_distance_to_node_m
    chain_pregate: bool = True
    # a loop factor's translation noise is at least this, per axis (metres)
    sigma_floor_m: float = 0.003
    # a loop factor's rotation noise is at least this, per axis (degrees)
    sigma_floor_deg: float = 0.15

    def __post_init__(self) -> None:
        if self.exclude_recent < 1 or self.top_k < 1 or self.max_verifications < 0 or self.partner_spacing < 0:
            raise ValueError("slam.loops: exclude_recent, top_k >= 1; max_verifications, partner_spacing >= 0")
        if self.search_every < 1:
            raise ValueError(f"slam.loops.search_every must be >= 1, got {self.search_every}")
        if not (-1 <= self.min_similarity <= 1):
            raise ValueError(f"slam.loops.min_similarity must be in [-1, 1], got {self.min_similarity}")
        if not (self.sigma_floor_m > 0 and self.sigma_floor_deg > 0):
            raise ValueError("slam.loops.sigma_floor_m and sigma_floor_deg must be > 0")


@dataclass(frozen=True)
class SlamGraphParams:
    """Robust optimisation of the pose graph (GTSAM graduated non-convexity over the loop factors)."""

    # a loop factor is an inlier while its whitened error is below the chi-square quantile at this probability
    inlier_probability: float = 0.99
    # a loop factor whose final GNC weight is above this counts as kept (else rejected by the optimiser)
    kept_weight: float = 0.5
    # gate loops before GNC: against the chain, then the largest pairwise consistent set (PCM; False: GNC alone)
    gate_loops: bool = True
    # a loop agrees with the chain (two loops with each other) within this plus the drift terms (metres)
    gate_floor_m: float = 0.1
    # a loop agrees with the chain (two loops with each other) within this plus the drift terms, in rotation (degrees)
    gate_floor_deg: float = 2.0
    # the chain's drift allowed per metre of chain path between the compared keyframes (fraction of the path)
    chain_drift_m_per_m: float = 0.1
    # the chain's rotation drift allowed per metre of chain path between the compared keyframes (degrees per metre)
    chain_drift_deg_per_m: float = 0.2
    # both bounds also grow by this many of the chain's own sigmas over the stretch (its edges' noise as a random walk)
    gate_sigmas: float = 3.0
    # the visual edges' covariance is multiplied by this in the optimisation (the refinement understates their error)
    visual_covariance_scale: float = 4.0

    def __post_init__(self) -> None:
        if not (0 < self.inlier_probability < 1) or not (0 < self.kept_weight < 1):
            raise ValueError("slam.graph.inlier_probability and kept_weight must be in (0, 1)")
        if not (np.isfinite(self.visual_covariance_scale) and self.visual_covariance_scale > 0):
            raise ValueError(f"slam.graph.visual_covariance_scale must be a finite number > 0, "
                             f"got {self.visual_covariance_scale}")
        for name in ("gate_floor_m", "gate_floor_deg", "chain_drift_m_per_m", "chain_drift_deg_per_m", "gate_sigmas"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise ValueError(f"slam.graph.{name} must be a finite number >= 0, got {v}")


@dataclass(frozen=True)
class SlamPlanarParams:
    """The platform's base moves on a floor (a wheeled or legged ground robot): between
    consecutive keyframes its base_link keeps its height, roll and pitch up to these sigmas."""

    # the base_link moves in a plane (a ground robot; off for a hand-held or flying camera)
    enabled: bool = False
    # height change of base_link between consecutive keyframes, one sigma (floor unevenness, gait; metres)
    sigma_height_m: float = 0.01
    # roll and pitch change of base_link between consecutive keyframes, one sigma (degrees)
    sigma_tilt_deg: float = 0.5
    # the whole pass is on one level floor (one storey, no ramps): base level and camera height held in the map frame
    level_floor: bool = False

    def __post_init__(self) -> None:
        for name in ("sigma_height_m", "sigma_tilt_deg"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"slam.planar.{name} must be a finite number > 0, got {v}")


@dataclass(frozen=True)
class SlamPlaneParams:
    """Walls as landmarks: vertical planes fitted to each keyframe's depth, one landmark per
    wall seen from several keyframes, holding the keyframes that see it to one plane."""

    # fit walls in each keyframe's depth and hold the keyframes that see one wall to that plane
    enabled: bool = True
    # points farther than this are not used for planes (their depth noise grows with range squared; metres)
    max_depth_m: float = 5.0
    # at most this many planes per keyframe (the largest first)
    max_per_keyframe: int = 4
    # RANSAC hypotheses per plane (pairs of points with the up direction)
    ransac_iterations: int = 150
    # a point lies on a plane within this plus `inlier_per_m2` times its depth squared (metres)
    inlier_m: float = 0.01
    # ... the depth-squared term of that bound (metres per square metre of depth)
    inlier_per_m2: float = 0.004
    # a plane needs this many of the keyframe's depth points (`mapping.keyframes.pixel_stride` grid)
    min_points: int = 30
    # a plane's points span at least this along the floor (metres)
    min_width_m: float = 1.0
    # ... and at least this along up (metres)
    min_height_m: float = 0.4
    # a wall's normal is within this of horizontal (degrees)
    max_tilt_deg: float = 8.0
    # an observation joins a wall within this angle of its normal (degrees) ...
    match_angle_deg: float = 6.0
    # ... this offset from its plane at the observation's centre (metres) ...
    match_offset_m: float = 0.15
    # ... and overlapping it along the floor or within this gap (metres)
    match_gap_m: float = 0.5
    # a wall becomes a landmark when this many keyframes see it
    min_keyframes: int = 3
    # one sigma of an observed plane's normal (radians)
    sigma_normal_rad: float = 0.01
    # one sigma of an observed plane's distance from the camera (metres)
    sigma_offset_m: float = 0.01
    # observations whose factor error (half the squared whitened error) exceeds this are dropped, then solved again
    outlier_error: float = 5.67

    def __post_init__(self) -> None:
        for name in ("max_depth_m", "inlier_m", "min_width_m", "min_height_m", "max_tilt_deg", "match_angle_deg",
                     "match_offset_m", "sigma_normal_rad", "sigma_offset_m", "outlier_error"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"slam.planes.{name} must be a finite number > 0, got {v}")
        for name in ("inlier_per_m2", "match_gap_m"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise ValueError(f"slam.planes.{name} must be a finite number >= 0, got {v}")
        for name in ("max_per_keyframe", "ransac_iterations", "min_points", "min_keyframes"):
            if getattr(self, name) < 1:
                raise ValueError(f"slam.planes.{name} must be >= 1, got {getattr(self, name)}")


@dataclass(frozen=True)
class SlamParams:
    """The mapping pass's SLAM (see the module docstring), and external trajectories (`--poses FILE`)."""

    # SLAM keyframes (the map's keyframe candidates) every this many mapping.keyframes steps (translation, rotation)
    keyframe_step_scale: float = 1.0
    # ... and the rotation step alone a further this many times (a robot turning in place sees the same place)
    keyframe_rotation_scale: float = 1.0
    # the robot's odometry as pose-graph edges
    odometry: SlamOdometryParams = field(default_factory=SlamOdometryParams)
    # visual edges between nearby keyframes, and visual odometry where odometry is missing
    visual: SlamVisualParams = field(default_factory=SlamVisualParams)
    # loop closures: candidates, verification, robust factors
    loops: SlamLoopParams = field(default_factory=SlamLoopParams)
    # robust optimisation of the pose graph
    graph: SlamGraphParams = field(default_factory=SlamGraphParams)
    # planar motion of a ground robot's base between consecutive keyframes
    planar: SlamPlanarParams = field(default_factory=SlamPlanarParams)
    # walls as plane landmarks in the final optimisation
    planes: SlamPlaneParams = field(default_factory=SlamPlaneParams)
    # matcher of visual edges and tracking (loops use models.matcher); PnP with depth verifies its matches
    vo_matcher: Literal["lightglue", "lightglue-int8", "lightglue-adaptive", "mnn", "nn-ratio"] = "mnn"
    # --poses FILE: frames in a gap of the trajectory longer than this get no pose (s; lost tracking)
    file_max_gap_s: float = 1.0

    def __post_init__(self) -> None:
        if not (np.isfinite(self.keyframe_step_scale) and self.keyframe_step_scale >= 1):
            raise ValueError(f"slam.keyframe_step_scale must be a finite number >= 1, got {self.keyframe_step_scale}")
        if not (np.isfinite(self.keyframe_rotation_scale) and self.keyframe_rotation_scale >= 1):
            raise ValueError("slam.keyframe_rotation_scale must be a finite number >= 1, "
                             f"got {self.keyframe_rotation_scale}")
        if not (np.isfinite(self.file_max_gap_s) and self.file_max_gap_s > 0):
            raise ValueError(f"slam.file_max_gap_s must be a finite number > 0, got {self.file_max_gap_s}")
