"""The distinctiveness check (GL without a trusted prior): does another place verify nearly as well?

The accepted candidate is judged against the other candidates' PnP poses (`distinct`): the
candidates verified so far, then the later ones worth verifying (`rivals_to_verify`), one at a
time, each skipped where PnP on its re-ranking matches (no model run) puts the camera at the
accepted pose's place (`distinctiveness.screen`). A rival resting on floor or ceiling tiles alone
does not count.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from litevloc.pipelines.localization.checks.pnp import PnpCheck
from litevloc.pipelines.localization.checks.support import SupportCheck, flat_at
from litevloc.pipelines.localization.distinct import (
    VerifiedPose,
    ambiguity,
    rivals_to_verify,
    same_place,
    strongest_rival,
)
from litevloc.pipelines.localization.query import Query, relative_pose
from litevloc.pipelines.localization.refine import RefineResult
from litevloc.pipelines.pnp import PnpResult

if TYPE_CHECKING:
    from litevloc.pipelines.localization.verifier import CandidateVerifier


def ambiguous(verifier: CandidateVerifier, winner: int, res: PnpResult, joint: RefineResult, q: Query,
              later: NDArray[np.int64], sims: NDArray[np.float32], verified: list[VerifiedPose],
              ratio: float | None = None) -> str:
    """The check of the GL pose `joint.T_map_camera` verified through `winner` (`res` its PnP),
    under the query's parameters: the refusal reason when a candidate at another place has at
    least 1/`ratio` of its inliers (default `distinctiveness.ratio`; 0: off), else ''. Judged on
    `verified` (the candidates verified so far), then on the `rivals_to_verify` among the `later`
    candidates one at a time (appended to `verified`), stopping once a rival decides. A rival
    whose pose rests on one horizontal plane (`support.flat_at`) is no evidence of another place."""
    p = q.params
    ratio = p.distinctiveness.ratio if ratio is None else ratio
    if ratio <= 0:
        return ""
    t0 = verifier.clock()
    more = rivals_to_verify([int(n) for n in later], q.rerank_counts, winner, ratio, p.distinctiveness.max_rivals)
    flat: dict[int, bool] = {}

    def substantive(v: VerifiedPose) -> bool:
        if v.node not in flat:
            flat[v.node] = flat_at(verifier, v.node, v.T_map_camera, q)
        return not flat[v.node]

    amb = ""
    for node in [None, *more]:
        if node is not None and not (p.distinctiveness.screen and _same_place_unmatched(verifier, node, q, joint)):
            verifier.run(node, float(sims[node]), q, [PnpCheck(verifier, q.params, evidence=verified),
                                                      SupportCheck(verifier)])
        # only a rival strong enough to decide is tested for flat support (a projection per rival)
        others = [v for v in verified if v.node != winner and v.n_inliers * ratio >= res.n_inliers and substantive(v)]
        rival = strongest_rival(joint.T_map_camera, others, p.distinctiveness.apart_m,
                                p.distinctiveness.apart_deg)
        amb = ambiguity(winner, res.n_inliers, rival, ratio)
        if amb:
            break
    q.timer.add("distinct", t0)
    return amb


def _same_place_unmatched(verifier: CandidateVerifier, node: int, q: Query, joint: RefineResult) -> bool:
    """Whether PnP on `node`'s re-ranking matches (mutual nearest neighbours, no model run)
    puts the live camera at the joint pose's place (`same_place`); False where it cannot
    tell (no such matches, no pose): the candidate is then verified with the matcher."""
    pairs = q.rerank_pairs.get(node)
    if pairs is None:
        return False
    m, p = verifier.map, q.params
    t0 = verifier.clock()
    res, _, _, _ = relative_pose(q.feats, q.depth, q.K, m.features[node], m.K[node], lambda a, b: pairs, p, None,
                                 m.keypoint_depth(node))
    q.timer.add("distinct_screen", t0)
    if res is None or not res.accepted or res.T_target_source is None:
        return False
    return same_place(m.T_map_camera[node] @ res.T_target_source, joint.T_map_camera, p.distinctiveness.apart_m,
                      p.distinctiveness.apart_deg)
