"""Global localization (GL): VPR top-k retrieval over the map, each candidate verified in order.

Candidates come by place-descriptor similarity, re-ordered by a cheap mutual-nearest-neighbour
count (`global_search.rerank`); each is verified (PnP, support, joint refinement: `verifier`) and the first
that passes wins, then the distinctiveness check judges it (no trusted prior), or the search
stops when the time budget would be overrun (`global_search.time_budget_ms`; while recovering after
tracking was lost, `global_search.lost_cost_ratio` x the median wall time of the last LL queries); the result
says why in `stop_reason`.

* A candidate that only its own keyframe confirms strongly (`global_search.vote_min_inliers`) is accepted
  with a fresh fused prior it agrees with (within the prior gate: the prior is the independent second
  view), or without a trusted prior where no candidate at another place verifies near as well
  (`confirm.gl_single_distinct_ratio`: distinctiveness stands in for the second keyframe); else it
  is returned, not accepted, as `LocalizationResult.provisional`.
* With the distinctiveness test off, a pose is still refused where a candidate verified before it at
  another place had at least as many PnP inliers (`distinctiveness.stronger_rival`).
* A GL pose outside a fused prior's gate gives way to a pose LL verifies at the prior's place
  (`global_search.check_prior_place`): in a repeating corridor both verify, the odometry tells them apart.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from litevloc.base.geometry import check_rigid, relative_pose_error
from litevloc.base.params.localization import LocalizationParams
from litevloc.pipelines.guided_matching import mutual_nn_pairs
from litevloc.pipelines.localization import prior as pg
from litevloc.pipelines.localization.checks.distinctiveness import ambiguous
from litevloc.pipelines.localization.checks.joint import JointCheck, single_keyframe
from litevloc.pipelines.localization.checks.pnp import PnpCheck
from litevloc.pipelines.localization.checks.pooled import PooledCheck
from litevloc.pipelines.localization.checks.second_look import SecondLookFn, look_again
from litevloc.pipelines.localization.checks.support import PooledSupportCheck, SupportCheck
from litevloc.pipelines.localization.distinct import VerifiedPose
from litevloc.pipelines.localization.local_search import LocalSearch
from litevloc.pipelines.localization.passes import pooled, with_pooled, with_second_passes
from litevloc.pipelines.localization.prior import Prior
from litevloc.pipelines.localization.query import Query, StageTimer
from litevloc.pipelines.localization.refusals import QueryRefusal, refusal_text
from litevloc.pipelines.localization.results import CandidateAttempt, LocalizationResult, ProvisionalPose
from litevloc.pipelines.localization.search_region import SearchRegion, nodes_within
from litevloc.pipelines.localization.verifier import Best, Check
from litevloc.pipelines.pnp import Refusal


def gl_budget_ms(p: LocalizationParams, ll_wall_ms: Sequence[float], nominal_ll_ms: float = float("inf")) -> float:
    """The wall-time bound (ms) on a GL query while recovering: `global_search.lost_cost_ratio` x the cost of
    an LL query, the median wall time of the last LL queries `ll_wall_ms` or `nominal_ll_ms` (the
    GL query's own feature extraction and VPR plus one candidate's verification: what an LL query
    that runs the matcher once costs) where lower or where no LL query has run; and
    `global_search.time_budget_ms` when set (the smaller bound); 0 = none."""
    bounds = [b for b in (p.global_search.time_budget_ms,) if b > 0]
    ll = min(float(np.median(ll_wall_ms)) if len(ll_wall_ms) else float("inf"), nominal_ll_ms)
    if p.global_search.lost_cost_ratio > 0 and np.isfinite(ll):
        bounds.append(p.global_search.lost_cost_ratio * ll)
    return min(bounds) if bounds else 0.0


LOOK_COST_WINDOW = 10  # second looks whose median wall time is the expected cost of the next one


class GlobalSearch:
    """GL over `local`'s verifier's map; `local` also verifies the prior's place;
    `second_look` (None: none) looks again at a refused query, `pooling`: whether weak
    candidates may be pooled (a later pass)."""

    def __init__(self, local: LocalSearch, second_look: SecondLookFn | None = None, pooling: bool = True) -> None:
        self.local, self.verifier = local, local.verifier
        self.second_look, self.pooling = second_look, pooling
        # wall times (ms) of the last second looks: the expected cost of the next (`_look_fits`)
        self.look_ms: deque[float] = deque(maxlen=LOOK_COST_WINDOW)
        self.budget_ms = 0.0  # the wall-time bound the last verification pass applied (0: none)

    def localize(self, t_ns: int, color: NDArray[np.uint8], depth: NDArray[np.float32] | None,
                 K: NDArray[np.float64], p: LocalizationParams, prior: Prior | None = None,
                 recovering_ll_ms: Sequence[float] | None = None, region: SearchRegion | None = None,
                 only: Sequence[int] | None = None) -> LocalizationResult:
        """GL under `p`. `prior`: fusion's pose (accepts a one-keyframe pose that agrees with it
        while fresh; an accepted pose outside its gate is measured against its place);
        `recovering_ll_ms` (after tracking was lost: the last LL queries' wall times) bounds the
        query's wall time by the LL cost, see `gl_budget_ms`; `region` (an initial pose)
        restricts the candidates to keyframes within it before the top-k cut; `only`: verify
        these nodes, in this order, instead of the retrieved candidates."""
        if prior is not None:
            prior = replace(prior, T_map_camera=check_rigid(prior.T_map_camera, "prior T_map_camera", atol=1e-4))
        v = self.verifier
        timer = StageTimer(v.clock)
        t_all = v.clock()
        q, desc = v.query(color, depth, K, p, timer)
        front_ms = (v.clock() - t_all) * 1e3  # feature extraction and VPR, as in an LL query
        sims = v.map.vpr @ desc
        order = (np.asarray(list(only), dtype=np.int64) if only is not None
                 else self.candidates(p, sims, q, region))

        def verify(pp: LocalizationParams) -> LocalizationResult:
            return self._search(t_ns, q.under(pp), sims, order, prior, recovering_ll_ms, (timer, t_all, front_ms))

        self.budget_ms = 0.0
        res = with_second_passes(verify, p, q.timer, v.map_has_depth, pooling=self.pooling)
        if not res.accepted and self.second_look is not None:
            short = self._look_short((v.clock() - t_all) * 1e3)
            if short:
                res = replace(res, stop_reason=f"{res.stop_reason}; no second look: {short}")
            else:
                res = look_again(self.second_look, p, res, (color, depth, K), prior)
                if "second_look" in res.timings_ms:
                    self.look_ms.append(res.timings_ms["second_look"])
        if not res.accepted or prior is None or not p.global_search.check_prior_place:
            return res
        return self._against_the_priors_place(res, q, desc, prior, t_all)

    def _look_short(self, spent_ms: float) -> str:
        """Why this GL query cannot afford the second look, '' when it can: `spent_ms` spent plus the
        median wall time of the last second looks (`look_ms`; none measured yet: it fits) must fit in
        the bound its verification passes applied (`global_search.time_budget_ms`, and while
        recovering `gl_budget_ms`; none: it fits). The look is part of the query its budget bounds."""
        if self.budget_ms <= 0 or not self.look_ms:
            return ""
        expected = float(np.median(self.look_ms))
        if spent_ms + expected <= self.budget_ms:
            return ""
        return (f"{spent_ms:.0f} ms spent + {expected:.0f} ms per look (median of the last {len(self.look_ms)}) "
                f"> the time budget ({self.budget_ms:.0f} ms)")

    def candidates(self, p: LocalizationParams, sims: NDArray[np.float32], q: Query,
                   region: SearchRegion | None = None) -> NDArray[np.int64]:
        """The map nodes GL verifies, in order (node ids, at most `global_search.top_k`): the
        `global_search.rerank_depth` most similar by place descriptor (`sims`, (N,) per node) among the
        keyframes within `region` (an initial pose) where one is given, re-ordered by local
        matches (`_rerank`), the first `global_search.top_k` of them. The one place where GL's candidate
        list is made: a filter on the candidates belongs here."""
        ranked = np.argsort(-sims, kind="stable")
        if region is not None:
            ranked = nodes_within(ranked, self.verifier.map.positions, region)
        shortlist = ranked[: max(p.global_search.top_k, p.global_search.rerank_depth if p.global_search.rerank else 0)]
        return self._rerank(p, shortlist, q)[: p.global_search.top_k]

    def _rerank(self, p: LocalizationParams, order: NDArray[np.int64], q: Query) -> NDArray[np.int64]:
        """The VPR candidates `order` (best first) re-ordered by their mutual-nearest-neighbour
        count with the live descriptors (`global_search.rerank`), VPR order breaking ties."""
        if not p.global_search.rerank or len(order) < 2:
            return order
        t0 = self.verifier.clock()
        live = np.asarray(q.feats.descriptors)
        feats = self.verifier.map.features
        least = p.global_search.rerank_min_similarity
        q.rerank_pairs = {int(n): mutual_nn_pairs(live, feats[int(n)].descriptors, least) for n in order}
        q.rerank_counts = {n: len(pairs[0]) for n, pairs in q.rerank_pairs.items()}
        counts = [q.rerank_counts[int(n)] for n in order]
        q.timer.add("rerank", t0)
        return order[np.argsort(-np.asarray(counts), kind="stable")]

    def _search(self, t_ns: int, q: Query, sims: NDArray[np.float32], order: NDArray[np.int64],
                prior: Prior | None, recovering_ll_ms: Sequence[float] | None,
                clock: tuple[StageTimer, float, float]) -> LocalizationResult:
        """One verification pass under the query's parameters: candidates in order, each verified
        and jointly refined at once; the first that passes the joint check wins (then the
        distinctiveness check), or one that agrees with a fresh prior; the time budget stops the
        search (`clock`: the query's timer, its start and its front end's ms)."""
        p, v = q.params, self.verifier
        timer, t_all, front_ms = clock
        attempts: list[CandidateAttempt] = []
        best: Best | None = None
        refusal = (QueryRefusal.NO_VPR_CANDIDATE, refusal_text(QueryRefusal.NO_VPR_CANDIDATE))
        stop = f"all {len(order)} VPR candidates tried"
        provisional: ProvisionalPose | None = None
        growth = 0.0 if prior is None else pg.growth_m(p, prior.age_s, True, prior.travel_m)
        evidence: list[VerifiedPose] = []  # every candidate's PnP pose, for the distinctiveness check
        trusted = prior is not None and pg.fresh(p, growth)
        floor = p.pnp.min_inliers  # a weaker candidate passes only pooled (see `passes.pooled_short`)
        min_kf = p.refine.min_keyframes
        joint_check = JointCheck(v, [int(n) for n in order],
                                 lambda c, weak: min_kf if p.confirm.gl or weak else 1, floor, refuse=False)
        checks: list[Check] = [PnpCheck(v, pooled(p), evidence=evidence), SupportCheck(v), joint_check,
                               PooledCheck(floor, min_kf), PooledSupportCheck(v, floor, min_kf)]
        budget = p.global_search.time_budget_ms
        candidates_ms = 0.0  # verification time (match, PnP, joint refinement) of the candidates so far
        first_ms = 0.0  # the first candidate's: with the front end, the nominal LL cost (`gl_budget_ms`)
        for k, node in enumerate(int(n) for n in order):
            spent = (v.clock() - t_all) * 1e3
            ahead = candidates_ms / max(k, 1)  # this query's mean cost per candidate so far
            if k == 1 and recovering_ll_ms is not None:
                budget = gl_budget_ms(p, recovering_ll_ms, nominal_ll_ms=front_ms + candidates_ms)
            if k > 0 and budget > 0 and spent + ahead > budget:
                stop = (f"time budget ({budget:.0f} ms) would be overrun: {spent:.0f} ms spent + "
                        f"{ahead:.0f} ms per candidate, after {k} of {len(order)} candidates")
                break
            t_cand = v.clock()
            c, refused_by = v.run(node, float(sims[node]), q, checks)
            candidates_ms += (v.clock() - t_cand) * 1e3
            first_ms = candidates_ms if k == 0 else first_ms
            if refused_by is not None:
                attempts.append(refused_by)
                continue
            res, att, joint = c.res, c.attempt, c.joint
            assert res is not None and att is not None and joint is not None
            if joint.accepted:
                attempts.append(att)
                best = (node, res, joint)
                stop = f"candidate {k + 1} of {len(order)} passed the joint check"
                amb = "" if trusted else ambiguous(v, node, res, joint, q, order[k + 1:], sims, evidence)
                if not amb and not trusted and p.distinctiveness.ratio <= 0 and p.distinctiveness.stronger_rival:
                    amb = ambiguous(v, node, res, joint, q, order[:0], sims, evidence, ratio=1.0)
                if amb:
                    best, provisional = None, None
                    refusal = (QueryRefusal.AMBIGUOUS, refusal_text(QueryRefusal.AMBIGUOUS, detail=amb))
                    stop = f"{stop}; {amb}"
                break
            single = single_keyframe(p, node, joint)
            if single is not None and prior is not None and pg.fresh(p, growth) and pg.within_gate(
                    p, single.T_map_camera, prior.T_map_camera, pg.gate_m(p, growth, fused=True), prior.cov):
                attempts.append(CandidateAttempt(node, att.similarity, att.matches, att.inliers,
                                                 "one keyframe only; agrees with the prior", Refusal.NONE))
                best = (node, res, replace(joint, accepted=True, reason="ok"))
                stop = f"candidate {k + 1} of {len(order)}: one keyframe, agrees with the prior"
                break
            single_ratio = p.confirm.gl_single_distinct_ratio
            if single is not None and not trusted and single_ratio > 0 and not ambiguous(
                    v, node, res, joint, q, order[k + 1:], sims, evidence, ratio=single_ratio):
                attempts.append(CandidateAttempt(node, att.similarity, att.matches, att.inliers,
                                                 "one keyframe only; no other place verifies near it", Refusal.NONE))
                best = (node, res, replace(joint, accepted=True, reason="ok"))
                stop = f"candidate {k + 1} of {len(order)}: one keyframe, no rival within x{single_ratio:g}"
                break
            if single is not None and (provisional is None or single.n_inliers > provisional.n_inliers):
                provisional = single
            attempts.append(CandidateAttempt(node, att.similarity, att.matches, att.inliers,
                                             f"joint refinement rejected: {joint.reason}"))
            refusal = (QueryRefusal.UNCONFIRMED, refusal_text(QueryRefusal.UNCONFIRMED, node=node))
        if recovering_ll_ms is not None and len(order):  # the bound, also where one candidate ended the pass
            budget = gl_budget_ms(p, recovering_ll_ms, nominal_ll_ms=front_ms + first_ms)
        self.budget_ms = max(self.budget_ms, budget)  # the widest bound of the query's passes bounds its look
        timer.add("total", t_all)
        out = replace(v.result(t_ns, "global", best, attempts, timer, refusal, q), stop_reason=stop,
                      candidates=tuple(int(n) for n in order))
        return out if out.accepted or provisional is None else replace(out, provisional=provisional)

    def _against_the_priors_place(self, res: LocalizationResult, q: Query, desc: NDArray[np.float32],
                                  prior: Prior, t_all: float) -> LocalizationResult:
        """The accepted GL result `res` measured against the fused `prior`: where the GL pose lies
        outside the prior's gate, LL's candidates at the prior are verified on the same query; a
        pose they give inside that gate (after LL's joint check) is the result instead, since the
        images verify both places and only the odometry tells them apart (a repeating corridor).
        Else `res`, its stop reason saying that the prior's place did not verify."""
        p = q.params
        assert res.T_map_camera is not None
        growth = pg.growth_m(p, prior.age_s, True, prior.travel_m)
        radius = pg.gate_m(p, growth, fused=True)
        if pg.within_gate(p, res.T_map_camera, prior.T_map_camera, radius, prior.cov):
            return res
        dt, _ = relative_pose_error(res.T_map_camera, prior.T_map_camera)
        q.timer.ms.pop("total", None)  # the whole query's, measured again below
        ll_params = p if self.pooling else with_pooled(p, 0)
        local = self.local.attempts(res.t_ns, q.under(ll_params), self.local.candidates(p, prior.T_map_camera, desc),
                                    prior.T_map_camera, (growth, radius, prior.cov), q.timer, t_all)
        why = f"GL's pose (node {res.ref_node}) lay {dt:.2f} m from the prior, outside its gate"
        attempts = res.attempts + local.attempts
        if not local.accepted:
            return replace(res, attempts=attempts, timings_ms=q.timer.ms,
                           stop_reason=f"{res.stop_reason}; {why}; the prior's place did not verify")
        return replace(local, attempts=attempts, stop_reason=f"{why}; the prior's place verified (node "
                       f"{local.ref_node}): the images verify both, the odometry tells them apart")
