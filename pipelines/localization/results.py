"""What one visual-localization query returns: the result, its candidates, matches and provisional pose."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from litevloc.pipelines.localization.refusals import QueryRefusal
from litevloc.pipelines.localization.tracking import TrackingState
from litevloc.pipelines.pnp import Refusal


@dataclass(frozen=True)
class CandidateAttempt:
    """One map node tried for a query, and why it was accepted or rejected (`reason` in words,
    `refusal` by kind: which gate refused it, `Refusal.NONE` when accepted)."""

    node: int
    similarity: float
    matches: int
    inliers: int
    reason: str
    refusal: Refusal = Refusal.LATER


@dataclass(frozen=True, eq=False)
class MatchedPixels:
    """The live frame's matches with the reference keyframe, for display and diagnosis.

    `live_px` (M, 2) and `keyframe_px` (M, 2) are pixel coordinates (x, y) in the live image and
    in the reference keyframe's image; `inlier` (M,) is True where the live keypoint, lifted with
    the live depth and moved by the accepted pose, reprojects into the keyframe within the PnP
    reprojection threshold (False also where the live keypoint has no depth).
    """

    keyframe: int
    live_px: NDArray[np.float32]
    keyframe_px: NDArray[np.float32]
    inlier: NDArray[np.bool_]


@dataclass(frozen=True, eq=False)
class ProvisionalPose:
    """A GL pose verified by one keyframe only (no second keyframe sees the place): not a fix.

    `T_map_camera` 4x4 (metres), `covariance` 6x6 camera-frame right perturbation
    (tx, ty, tz, rx, ry, rz) from the single-keyframe solve; `node` the keyframe, `n_inliers`
    its inliers under the pose."""

    T_map_camera: NDArray[np.float64]
    covariance: NDArray[np.float64]
    node: int
    n_inliers: int


@dataclass(frozen=True, eq=False)
class LocalizationResult:
    """Outcome of one query. `accepted` False means "not localized" (pose is None); `refusal` says
    why by kind, `reason` in words with its numbers."""

    t_ns: int
    mode: str  # "global" | "local"
    accepted: bool
    reason: str
    T_map_camera: NDArray[np.float64] | None = None
    covariance: NDArray[np.float64] | None = None  # 6x6, camera-frame perturbation (t, rotvec)
    ref_node: int = -1
    n_matches: int = 0
    n_inliers: int = 0
    inlier_ratio: float = 0.0
    median_reprojection_px: float = float("nan")
    attempts: tuple[CandidateAttempt, ...] = ()
    timings_ms: dict[str, float] = field(default_factory=dict)
    keyframes: tuple[int, ...] = ()  # keyframes whose matches support the pose (joint refinement)
    stop_reason: str = ""  # GL: why the candidate search stopped (passed, all tried, time budget)
    matches: MatchedPixels | None = None  # accepted results: matches with `ref_node`, inliers marked
    provisional: ProvisionalPose | None = None  # rejected GL results only (see ProvisionalPose)
    candidates: tuple[int, ...] = ()  # GL: the nodes it would verify, in order (`global_candidates`)
    tracking_state: TrackingState | None = None  # the localizer's state after this query, when the caller reports it
    refusal: QueryRefusal = QueryRefusal.NONE  # why it was not localized, by kind (NONE: accepted)
    second_look: bool = False  # accepted by the full-resolution second look (`checks.second_look.look_again`)


def refused(res: LocalizationResult, refusal: QueryRefusal, reason: str) -> LocalizationResult:
    """`res` not accepted, for `refusal` (`reason` its words): its pose, covariance and matches removed."""
    return replace(res, accepted=False, T_map_camera=None, covariance=None, matches=None, reason=reason,
                   refusal=refusal)
