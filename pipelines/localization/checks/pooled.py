"""The pooled check: a weak candidate (fewer PnP inliers than the floor) passes only where the
joint refinement's keyframes explain the floor together (`passes.pooled_short`)."""

from __future__ import annotations

from dataclasses import dataclass, replace

from litevloc.pipelines.localization.passes import pooled_short
from litevloc.pipelines.localization.query import Query
from litevloc.pipelines.localization.results import CandidateAttempt
from litevloc.pipelines.localization.verifier import Candidate
from litevloc.pipelines.pnp import Refusal


@dataclass(frozen=True)
class PooledCheck:
    """`floor`: the PnP inlier floor of a strong candidate; `min_keyframes`: the keyframes a weak
    one's joint refinement needs."""

    floor: int
    min_keyframes: int

    def __call__(self, c: Candidate, q: Query) -> CandidateAttempt | None:
        assert c.res is not None and c.attempt is not None
        short = pooled_short(c.res, c.joint, self.floor, self.min_keyframes)
        return replace(c.attempt, reason=short, refusal=Refusal.INLIERS) if short else None
