"""Loop closures: candidates from the keyframes' place descriptors, verified like a GL query.

Candidates (`LoopSearch.candidates`): the `top_k` keyframes most similar to the new one
(cosine of the VPR descriptors, at least `min_similarity`) among those older than
`exclude_recent` keyframes; never all pairs, and at most `max_verifications` are verified
per keyframe (each costs one run of the localizer's matcher). Only every `search_every`-th
keyframe (the loop-search keyframes) searches and is a candidate: consecutive keyframes
overlap, so their neighbours' views still confirm a loop, and the matcher runs drop by
that factor. With `loops.chain_pregate`, a
candidate of the new keyframe's chain is skipped before that bound when the chain places it
farther away than the chain gate (`pipelines.slam.consistency`) could accept for any loop
verification can return (a verified loop is at most `localization.verify.max_distance_to_node_m`
long): in a corridor whose texture repeats, most candidates are such repetitions.

Verification (`verify_loop`) is the localizer's own geometry (`pipelines.localization`):
the new keyframe plays the live frame (its keypoints lifted with its depth) and the candidate
and its neighbours in their chain play map keyframes, posed by their initial (chained)
estimates, which are consistent over so short a stretch. Matcher + PnP with depth into the
candidate (`localization.pnp`, `verify.min_matches`, `verify.max_distance_to_node_m`), then the joint
refinement over the candidate and its neighbours matched by projection
(`localization.refine`): accepted only when a second keyframe agrees. The loop factor is the
joint pose relative to the candidate, with the refinement's covariance (its noise model
without the systematic terms of live queries, floored by `loops.sigma_floor_*`, as the
visual edges: both come from the same two-keyframe geometry).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from litevloc.base.geometry import invert
from litevloc.base.params.localization import LocalizationParams
from litevloc.base.params.slam import SlamGraphParams, SlamLoopParams
from litevloc.pipelines.localization.refine import KeyframeObservations, guided_matches, refine_pose
from litevloc.pipelines.pnp import solve_pnp
from litevloc.pipelines.slam.consistency import translation_bound
from litevloc.pipelines.slam.frontend import edge_refine_params
from litevloc.pipelines.slam.types import Edge, Keyframe, LoopAttempt, MatchFn

_RT = [3, 4, 5, 0, 1, 2]  # (t, rotvec) -> GTSAM's (rotvec, t)


class LoopSearch:
    """Place-descriptor candidates among older keyframes (see the module docstring); only the
    loop-search keyframes (every `search_every`-th) are added and searched."""

    def __init__(self, params: SlamLoopParams) -> None:
        self.params = params
        self._vpr = np.zeros((0, 0), np.float32)
        self._ids = np.zeros(0, np.int64)
        self._n = 0

    def add(self, kf_id: int, vpr: NDArray[np.float32]) -> None:
        """Append keyframe `kf_id`'s descriptor (ids increasing)."""
        v = np.asarray(vpr, np.float32).reshape(-1)
        if self._n == len(self._vpr):
            grown = np.zeros((max(64, 2 * self._n), len(v)), np.float32)
            ids = np.zeros(len(grown), np.int64)
            if self._n:
                grown[: self._n], ids[: self._n] = self._vpr[: self._n], self._ids[: self._n]
            self._vpr, self._ids = grown, ids
        self._vpr[self._n], self._ids[self._n] = v, kf_id
        self._n += 1

    def candidates(self, kf_id: int, vpr: NDArray[np.float32]) -> list[tuple[int, float]]:
        """(keyframe id, similarity) of the candidates for keyframe `kf_id` with descriptor `vpr`,
        most similar first."""
        older = int(np.searchsorted(self._ids[: self._n], kf_id - self.params.exclude_recent))
        if older <= 0:
            return []
        sims = self._vpr[:older] @ np.asarray(vpr, np.float32).reshape(-1)
        order = np.argsort(-sims, kind="stable")[: self.params.top_k]
        return [(int(self._ids[j]), float(sims[j])) for j in order if sims[j] >= self.params.min_similarity]


def _observations(q: Keyframe, kf: Keyframe, i_q: NDArray[np.int64], i_k: NDArray[np.int64]) -> KeyframeObservations:
    """The query keyframe's lifted points matched to keyframe `kf` (posed by its initial estimate)."""
    pts = q.points[i_q]
    ok = np.all(np.isfinite(pts), axis=1)
    depth = kf.features.depth
    return KeyframeObservations(kf.id, pts[ok], np.asarray(kf.features.keypoints, np.float64)[i_k[ok]], kf.K,
                                kf.T_init, None if depth is None else np.asarray(depth, np.float64)[i_k[ok]])


def verify_loop(q: Keyframe, cand: Keyframe, views: list[Keyframe], match: MatchFn, loc: LocalizationParams,
                params: SlamLoopParams, similarity: float) -> tuple[Edge | None, LoopAttempt]:
    """Verify the loop `cand` -> `q` (see the module docstring); `views`: the candidate's
    neighbours that may confirm it. Returns the loop edge (None when rejected) and the attempt."""

    def reject(reason: str, inliers: int = 0) -> tuple[Edge | None, LoopAttempt]:
        return None, LoopAttempt(q.id, cand.id, similarity, False, reason, inliers)

    i_q, i_c = match(q.features, cand.features)
    i_q, i_c = np.asarray(i_q, np.int64), np.asarray(i_c, np.int64)
    first = _observations(q, cand, i_q, i_c)
    if len(first.points_live) < max(loc.verify.min_matches, loc.pnp.min_inliers):
        return reject(f"too few matches with depth ({len(first.points_live)})")
    res = solve_pnp(first.points_live, first.pixels, cand.K, loc.pnp)
    if not res.accepted or res.T_target_source is None:
        return reject(res.reason, res.n_inliers)
    if float(np.linalg.norm(res.T_target_source[:3, 3])) > loc.verify.max_distance_to_node_m:
        return reject(f"pose {np.linalg.norm(res.T_target_source[:3, 3]):.1f} m from the candidate", res.n_inliers)
    T0 = cand.T_init @ res.T_target_source
    obs = [first]
    for v in views[: max(loc.refine.max_keyframes - 1, 1)]:
        i_qv, i_v = guided_matches(q.points, q.features.descriptors, T0, v.features.keypoints, v.features.descriptors,
                                   v.K, v.T_init, loc.refine)
        obs.append(_observations(q, v, np.asarray(i_qv, np.int64), np.asarray(i_v, np.int64)))
    joint = refine_pose(T0, obs, edge_refine_params(loc.refine, params.sigma_floor_m, params.sigma_floor_deg))
    if not joint.accepted or joint.covariance is None:
        return reject(f"no second view: {joint.reason}", res.n_inliers)
    cov = np.asarray(joint.covariance, np.float64)[np.ix_(_RT, _RT)]
    edge = Edge(cand.id, q.id, invert(cand.T_init) @ joint.T_map_camera, cov, "loop", inliers=joint.n_inliers,
                similarity=similarity)
    return edge, LoopAttempt(q.id, cand.id, similarity, True, "ok", joint.n_inliers)


@dataclass
class LoopCounts:
    """Loop-closure counters for the report."""

    candidates: int = 0  # place-descriptor candidates found (before the verification bound)
    pregated: int = 0  # skipped unmatched: the chain places them too far for the chain gate to accept
    tried: int = 0  # verified with the matcher
    verified: int = 0  # passed the geometry


def neighbour_views(cand: Keyframe, keyframes: list[Keyframe]) -> list[Keyframe]:
    """The candidate's temporal neighbours in its chain (next first, then previous)."""
    out = []
    for j in (cand.id + 1, cand.id - 1):
        if 0 <= j < len(keyframes) and keyframes[j].chain == cand.chain:
            out.append(keyframes[j])
    return out


def beyond_chain_gate(q: Keyframe, cand: Keyframe, gate: SlamGraphParams, max_loop_m: float) -> bool:
    """Would the chain gate reject any loop `cand` -> `q` at most `max_loop_m` long? True when
    both lie on one chain whose initial poses put them farther apart than the gate's bound over
    the path between them plus `max_loop_m` (triangle inequality on the translations)."""
    if q.chain != cand.chain:
        return False
    apart = float(np.linalg.norm(q.T_init[:3, 3] - cand.T_init[:3, 3]))
    bound = translation_bound(abs(q.path_m - cand.path_m), abs(q.path_var_t - cand.path_var_t), gate)
    return apart > float(bound) + max_loop_m


def loop_closures(q: Keyframe, keyframes: list[Keyframe], search: LoopSearch, match: MatchFn,
                  loc: LocalizationParams, params: SlamLoopParams, counts: LoopCounts,
                  gate: SlamGraphParams | None = None) -> tuple[list[Edge], list[LoopAttempt]]:
    """Loop edges for keyframe `q` (a loop-search keyframe): candidates (without those
    `beyond_chain_gate` of the chain `gate`, when given), then at most `max_verifications`
    verified, skipping candidates near a partner already found."""
    edges: list[Edge] = []
    attempts: list[LoopAttempt] = []
    cands = search.candidates(q.id, q.vpr)
    counts.candidates += len(cands)
    if gate is not None:
        reach = loc.verify.max_distance_to_node_m
        near = [(j, s) for j, s in cands if not beyond_chain_gate(q, keyframes[j], gate, reach)]
        counts.pregated += len(cands) - len(near)
        cands = near
    for j, sim in cands:
        if len(attempts) >= params.max_verifications:
            break
        if any(abs(j - e.a) <= params.partner_spacing for e in edges):
            continue
        counts.tried += 1
        edge, att = verify_loop(q, keyframes[j], neighbour_views(keyframes[j], keyframes), match, loc, params, sim)
        attempts.append(att)
        if edge is not None:
            counts.verified += 1
            edges.append(edge)
    return edges, attempts
