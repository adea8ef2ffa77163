"""Local localization (LL): from a prior pose, the map nodes around it verified in order.

The nearest map node and its covisibility neighbours within `local_search.candidate_radius_m` and
`local_search.max_view_angle_deg` are ranked by descriptor similarity; candidates are tried in that order
until one passes every check (a rejected candidate hands over to the next): PnP (on matches
guided by a fresh prior first), the prior gate, the joint refinement (unless the pose lies close
to a fresh prior) and, for a weak candidate, the pooled inlier count. A query every pass refused
is looked at again at full resolution where that is configured (`checks.second_look`).

Where only the second look accepted the last LL query (views the first look's coarser features do
not hold, e.g. close to a finely textured surface), the next one with a fresh prior does not spend
the matcher model on every candidate first (`second_look.stay`, off by default: on 7-Scenes it
costs a point at 25 cm / 5 deg): its first look runs the model only for the keyframes that
accepted last time (guided matches for all), and a refusal goes to the second look, which takes
those keyframes where the first look's attempts leave room. A first-look acceptance ends this.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from litevloc.base.geometry import check_rigid, relative_pose_error
from litevloc.base.params.localization import LocalizationParams
from litevloc.pipelines.localization import prior as pg
from litevloc.pipelines.localization.checks.joint import JointCheck
from litevloc.pipelines.localization.checks.pnp import PnpCheck
from litevloc.pipelines.localization.checks.pooled import PooledCheck
from litevloc.pipelines.localization.checks.prior_gate import PriorGateCheck
from litevloc.pipelines.localization.checks.second_look import SecondLookFn, look_again
from litevloc.pipelines.localization.passes import pooled, with_second_passes
from litevloc.pipelines.localization.prior import Prior
from litevloc.pipelines.localization.query import Query, StageTimer
from litevloc.pipelines.localization.refusals import QueryRefusal, refusal_text
from litevloc.pipelines.localization.results import CandidateAttempt, LocalizationResult
from litevloc.pipelines.localization.verifier import Best, Candidate, CandidateVerifier, Check

Gate = tuple[float, float, NDArray[np.float64] | None]  # the prior's growth (m), gate radius (m), position covariance


class LocalSearch:
    """LL over `verifier`'s map; `second_look` (None: none) looks again at a refused query,
    `pooling`: whether weak candidates may be pooled (a later pass)."""

    def __init__(self, verifier: CandidateVerifier, second_look: SecondLookFn | None = None,
                 pooling: bool = True) -> None:
        self.verifier, self.second_look, self.pooling = verifier, second_look, pooling
        # the keyframes of the last LL query if only its second look accepted it, else ()
        self.full_resolution: tuple[int, ...] = ()

    def candidates(self, p: LocalizationParams, prior: NDArray[np.float64],
                   desc: NDArray[np.float32]) -> list[tuple[int, float]]:
        """(node, similarity) candidates for a prior pose, best first; empty if none is near.

        The nearest node (none if farther than `local_search.trigger_distance_m`), its covisible
        neighbours and every node within `local_search.candidate_radius_m` that faces within
        `local_search.max_view_angle_deg` of the prior, ranked by VPR similarity; looked up in the map's
        KD-tree node index (`TopoMap.node_index`), so the cost does not grow with the map."""
        m = self.verifier.map
        return m.node_index.local_candidates(
            prior, desc, m.vpr, m.T_map_camera, self.verifier.neighbours, p.local_search.candidate_radius_m,
            p.local_search.trigger_distance_m, p.local_search.max_view_angle_deg, p.local_search.max_candidates)

    def localize(self, t_ns: int, color: NDArray[np.uint8], depth: NDArray[np.float32] | None,
                 K: NDArray[np.float64], p: LocalizationParams, prior: Prior,
                 only: Sequence[int] | None = None) -> LocalizationResult:
        """LL from `prior` under `p` (`only`: these nodes, in this order, instead of the prior's
        candidates). A candidate's pose must pass the prior gate (`prior.growth_m`: at the fused
        rate for fusion's prior, at the robot's top speed for the last VLoc pose, narrowed by
        fusion's covariance, `prior.gate_toward`)."""
        T_prior = check_rigid(prior.T_map_camera, "prior T_map_camera", atol=1e-4)
        v = self.verifier
        timer = StageTimer(v.clock)
        t_all = v.clock()
        q, desc = v.query(color, depth, K, p, timer)
        if only is None:
            cands = self.candidates(p, T_prior, desc)
        else:
            sims = v.map.vpr @ desc
            cands = [(int(n), float(sims[int(n)])) for n in only]
        growth = pg.growth_m(p, prior.age_s, prior.fused, prior.travel_m)
        gate = (growth, pg.gate_m(p, growth, prior.fused), prior.cov)
        fresh = pg.fresh(p, growth)
        look = self.second_look if p.second_look.local else None
        stay = self.full_resolution if look is not None and fresh and p.second_look.stay else ()
        first = q.matching_only(stay) if stay else q
        res = with_second_passes(lambda pp: self.attempts(t_ns, first.under(pp), cands, T_prior, gate, timer, t_all),
                                 p, q.timer, v.map_has_depth, allowed=fresh, pooling=self.pooling)
        if not res.accepted and look is not None:
            res = look_again(look, p, res, (color, depth, K),
                             replace(prior, T_map_camera=T_prior), local=True, also=stay)
        self.full_resolution = res.keyframes if res.accepted and res.second_look else ()
        return res

    def attempts(self, t_ns: int, q: Query, cands: list[tuple[int, float]], prior: NDArray[np.float64],
                 gate: Gate, timer: StageTimer, t_all: float) -> LocalizationResult:
        """LL's candidates `cands` (node, similarity) tried in order under the query's parameters
        until one passes the prior gate (`gate`) and the joint refinement (see `localize`)."""
        p, v = q.params, self.verifier
        growth, gate_m, cov = gate
        attempts: list[CandidateAttempt] = []
        best: Best | None = None
        fresh = pg.fresh(p, growth)
        guided_first = p.local_search.guided_min_matches > 0 and fresh
        floor = p.pnp.min_inliers  # a weaker candidate passes only pooled (see `passes.pooled_short`)
        min_kf = p.refine.min_keyframes

        def need(c: Candidate, weak: bool) -> int:
            """Keyframes the joint refinement needs: one where the pose lies close to a fresh prior."""
            assert c.T_map_camera is not None
            dt, dr = relative_pose_error(c.T_map_camera, prior)
            close = dt <= p.confirm.skip_within_m and dr <= p.confirm.skip_within_deg and fresh and not weak
            return min_kf if (p.confirm.ll and not close) or weak else 1

        checks: list[Check] = [PnpCheck(v, pooled(p), guided_prior=prior if guided_first else None),
                               PriorGateCheck(prior, gate_m, cov),
                               JointCheck(v, [n for n, _ in cands], need, floor, refuse=True),
                               PooledCheck(floor, min_kf)]
        for node, sim in cands:
            c, refused_by = v.run(node, sim, q, checks)
            if refused_by is not None:
                attempts.append(refused_by)
                continue
            assert c.res is not None and c.attempt is not None and c.joint is not None
            attempts.append(c.attempt)
            best = (node, c.res, c.joint)
            break
        timer.add("total", t_all)
        kind = QueryRefusal.NO_NODE_NEAR_PRIOR if not cands else QueryRefusal.NO_CANDIDATE
        return v.result(t_ns, "local", best, attempts, timer, (kind, refusal_text(kind)), q)
