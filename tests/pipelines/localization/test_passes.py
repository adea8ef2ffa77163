"""The later verification passes (`pipelines.localization.passes`): which run, in which order, under
which parameters, and what a refused query's result keeps of them."""

from __future__ import annotations

from dataclasses import replace

from litevloc.base.params.localization import LocalizationParams, PassesParams, VerifyParams
from litevloc.pipelines.localization.passes import passes, with_second_passes
from litevloc.pipelines.localization.query import StageTimer
from litevloc.pipelines.localization.results import CandidateAttempt, LocalizationResult
from litevloc.pipelines.pnp import Refusal

MAP_DEPTH, POOLED = "verified again with the map's depth", "verified again with weak candidates pooled"


def test_the_map_depth_pass_runs_only_where_allowed_and_the_map_has_depth_and_pooling_comes_last() -> None:
    p = LocalizationParams(passes=PassesParams(map_depth=True, pooled_min_inliers=20),
                           verify=VerifyParams(map_depth=False))
    full = passes(p, map_has_depth=True, allowed=True)
    assert [how for _, how in full] == ["", MAP_DEPTH, POOLED]
    first, depth, pooled = (params for params, _ in full)
    assert first.passes.pooled_min_inliers == 0 and not first.verify.map_depth
    assert depth.verify.map_depth and depth.passes.pooled_min_inliers == 0
    assert pooled.verify.map_depth and pooled.passes.pooled_min_inliers == 20  # built on the pass before it
    assert [how for _, how in passes(p, map_has_depth=False, allowed=True)] == ["", POOLED]
    assert [how for _, how in passes(p, map_has_depth=True, allowed=False)] == ["", POOLED]
    assert [how for _, how in passes(replace(p, passes=replace(p.passes, pooled_min_inliers=0)), True, True)] == ["",
                                                                                                                  MAP_DEPTH]


def test_a_refused_query_keeps_every_pass_s_attempts_and_pools_only_where_a_candidate_was_weak() -> None:
    p = LocalizationParams(passes=PassesParams(map_depth=True, pooled_min_inliers=20),
                           verify=VerifyParams(map_depth=False))
    weak = CandidateAttempt(3, 0.5, 60, 25, "too few inliers", Refusal.INLIERS)
    hopeless = CandidateAttempt(4, 0.4, 12, 0, "too few matches (12)", Refusal.MATCHES)
    ran: list[str] = []

    def verify_with(first: CandidateAttempt) -> LocalizationResult:
        ran.clear()

        def verify(params: LocalizationParams) -> LocalizationResult:
            ran.append("pooled" if params.passes.pooled_min_inliers
                       else "map depth" if params.verify.map_depth else "first")
            att = first if len(ran) == 1 else CandidateAttempt(5, 0.3, 10, 0, "no", Refusal.MATCHES)
            return LocalizationResult(0, "global", False, f"refused {len(ran)}", attempts=(att,))
        return with_second_passes(verify, p, StageTimer(), map_has_depth=True)

    res = verify_with(weak)
    assert ran == ["first", "map depth", "pooled"]
    assert [a.node for a in res.attempts] == [3, 5, 5] and res.reason == "refused 3"
    assert POOLED in res.stop_reason and "refused 1; refused 2" in res.stop_reason
    verify_with(hopeless)
    assert ran == ["first", "map depth"]  # no candidate a floor of 20 could let through
