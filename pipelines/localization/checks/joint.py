"""The joint-refinement check, and its one-keyframe outcome: a provisional pose.

A GL candidate the joint refinement refuses only for want of a second consistent keyframe, but
that its own keyframe explains strongly (`global_search.vote_min_inliers`), is a provisional pose: not a
fix, a vote fusion may count, or a fix where a fresh fused prior agrees with it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from litevloc.base.params.localization import LocalizationParams
from litevloc.pipelines.localization.query import Query
from litevloc.pipelines.localization.refine import RefineResult
from litevloc.pipelines.localization.results import CandidateAttempt, ProvisionalPose
from litevloc.pipelines.localization.verifier import Candidate, CandidateVerifier


@dataclass(frozen=True, eq=False)
class JointCheck:
    """The joint refinement of a PnP-verified candidate over its keyframe and covisible ones
    (`CandidateVerifier.joint`, `fallback` nodes after the neighbours), needing
    `min_keyframes(candidate, weak)` consistent keyframes (`weak`: fewer PnP inliers than
    `floor`); `refuse`: a strong candidate the solve does not accept is refused here (LL; GL
    decides on it itself: a provisional pose, or one a fresh prior confirms)."""

    verifier: CandidateVerifier
    fallback: list[int]
    min_keyframes: Callable[[Candidate, bool], int]
    floor: int
    refuse: bool

    def __call__(self, c: Candidate, q: Query) -> CandidateAttempt | None:
        assert c.res is not None and c.attempt is not None and c.T_map_camera is not None
        weak = c.res.n_inliers < self.floor
        c.joint = self.verifier.joint(c.node, c.T_map_camera, q, self.fallback, self.min_keyframes(c, weak))
        if self.refuse and not c.joint.accepted and not weak:  # a weak one is refused by the pooled check
            return CandidateAttempt(c.node, c.similarity, c.attempt.matches, c.attempt.inliers,
                                    f"joint refinement rejected: {c.joint.reason}")
        return None


def single_keyframe(p: LocalizationParams, node: int, joint: RefineResult) -> ProvisionalPose | None:
    """The joint solve's pose when it failed only for want of a second keyframe and `node`
    itself explains at least `global_search.vote_min_inliers` matches under it; else None."""
    rp, need = p.refine, p.global_search.vote_min_inliers
    if need <= 0 or joint.accepted or joint.covariance is None:
        return None
    if joint.consistent_keyframes >= rp.min_keyframes or joint.inliers_per_keyframe.get(node, 0) < need:
        return None
    if joint.shift_m > rp.max_shift_m or joint.shift_deg > rp.max_shift_deg:
        return None
    return ProvisionalPose(joint.T_map_camera, joint.covariance, node, joint.inliers_per_keyframe[node])
