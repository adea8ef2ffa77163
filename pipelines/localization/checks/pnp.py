"""The PnP check: the candidate keyframe matched and PnP + RANSAC solved into it (`query.relative_pose`).

LL with a fresh prior first tries matches guided by the prior (no model run) and falls back to
the matcher's where those are too few or their PnP fails (`local_search.guided_min_matches`).
GL keeps every candidate's PnP pose, accepted or not, as evidence for the distinctiveness check.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from litevloc.base.params.localization import LocalizationParams
from litevloc.pipelines.localization.distinct import VerifiedPose
from litevloc.pipelines.localization.query import Query
from litevloc.pipelines.localization.results import CandidateAttempt
from litevloc.pipelines.localization.verifier import Candidate, CandidateVerifier


@dataclass(frozen=True, eq=False)
class PnpCheck:
    """PnP under `pnp_params` (its gates; the query's parameters for the rest); `guided_prior`
    (4x4, a fresh prior) guides the matches first; `evidence` collects every PnP pose."""

    verifier: CandidateVerifier
    pnp_params: LocalizationParams
    guided_prior: NDArray[np.float64] | None = None
    evidence: list[VerifiedPose] | None = None

    def __call__(self, c: Candidate, q: Query) -> CandidateAttempt | None:
        v, node = self.verifier, c.node
        guided = self.guided_prior is not None and q.try_guided(node, self.guided_prior,
                                                                q.params.local_search.guided_min_matches)
        res, att = v.verify(node, q, c.similarity, self.pnp_params)
        if guided and not (res is not None and res.accepted):
            q.forget(node)
            res, att = v.verify(node, q, c.similarity, self.pnp_params)
        if self.evidence is not None and res is not None and res.T_target_source is not None:
            self.evidence.append(VerifiedPose(node, v.map.T_map_camera[node] @ res.T_target_source, res.n_inliers))
        if res is None or not res.accepted or res.T_target_source is None:
            return att
        c.res, c.attempt = res, att
        c.T_map_camera = v.map.T_map_camera[node] @ res.T_target_source
        return None
