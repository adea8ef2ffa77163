"""The joint-refinement check's one-keyframe outcome: a provisional pose.

A GL candidate the joint refinement refuses only for want of a second consistent keyframe, but
that its own keyframe explains strongly (`global_search.vote_min_inliers`), is a provisional pose: not a
fix, a vote fusion may count, or a fix where a fresh fused prior agrees with it.
"""

from __future__ import annotations

from litevloc.base.params.localization import LocalizationParams
from litevloc.pipelines.localization.refine import RefineResult
from litevloc.pipelines.localization.results import ProvisionalPose


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
