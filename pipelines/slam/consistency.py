"""Loops gated before the robust optimiser: against the chain, then against each other.

A corridor whose texture repeats verifies loops shifted by one repetition: the two keyframes
see the same pattern, and so does the second view that must agree. Such loops can outnumber
the true revisits, and a robust optimiser over all of them then keeps wrong ones or, with
most loops wrong, hardly any. Two checks before it use what a shifted loop cannot fake: the
chain (odometry and visual edges, solved without loops), accurate over short stretches.

* Chain gate: a loop between two keyframes of one chain must agree with the chain's own
  relative pose of them within `gate_floor_*` + `chain_drift_*_per_m` x the path travelled
  between them along the chain + `gate_sigmas` x the chain's own sigma over that stretch (the
  edges' noise accumulated as a random walk: where only the odometry bridges a blackout, its
  larger noise widens the bound). A loop shifted by one repetition disagrees by about the path
  between its keyframes; a true revisit by the chain's drift over that path.
* Pairwise consistency (PCM: J. G. Mangelson, D. Dominic, R. M. Eustice, R. Vasudevan,
  "Pairwise Consistent Measurement Set Maximization for Robust Multi-robot Map Merging",
  ICRA 2018): loops i and j are consistent when the cycle a_i -loop i-> b_i -chain-> b_j
  -loop j^-1-> a_j -chain-> a_i closes within the same bound over the chain paths a_i..a_j
  and b_i..b_j. The largest set of pairwise consistent loops is kept: a maximum clique of the
  consistency graph, found greedily (PCM's heuristic). Loops shifted by one repetition agree
  among themselves but not with the true revisits.

Loops whose keyframes lie in chains the cycle cannot relate (two different pairs of chains)
are taken as consistent with each other: no chain path says otherwise.

Poses are 4x4 `T_map_camera` of the chain solution (each chain in its own frame); loops
`T_a_b` map points of keyframe b's camera into keyframe a's (metres, radians).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from litevloc.base.geometry import invert
from litevloc.base.params.slam import SlamGraphParams
from litevloc.pipelines.slam.types import F64, Edge

CHAIN = "chain gate"
PAIRWISE = "pairwise consistency"
NO_CHAIN = "keyframe without a chain pose"


@dataclass(frozen=True)
class ChainPath:
    """Where each keyframe lies on its chain, by keyframe id: `chain` id, `s` the path length
    (m) from the chain's first keyframe, `var_t` / `var_r` the edges' variances accumulated
    from there (m^2, rad^2: per step the most certain edge into the keyframe, its largest
    axis); `poses` the chain solution's T_map_camera."""

    chain: dict[int, int]
    s: dict[int, float]
    var_t: dict[int, float]
    var_r: dict[int, float]
    poses: dict[int, F64]


def chain_path(ids_chains: Sequence[tuple[int, int]], poses: dict[int, F64], edges: Sequence[Edge]) -> ChainPath:
    """`ChainPath` of the keyframes (id, chain) that have a pose, from the chain solution's
    camera positions (keyframes in id order) and the odometry and visual `edges`."""
    step_t: dict[int, float] = {}
    step_r: dict[int, float] = {}
    for e in edges:
        if e.kind in ("loop", "planar"):
            continue
        d = np.diag(e.covariance)
        step_t[e.b] = min(step_t.get(e.b, np.inf), float(d[3:].max()))
        step_r[e.b] = min(step_r.get(e.b, np.inf), float(d[:3].max()))
    s: dict[int, float] = {}
    vt: dict[int, float] = {}
    vr: dict[int, float] = {}
    chain: dict[int, int] = {}
    last: dict[int, int] = {}
    for i, c in sorted(ids_chains):
        if i not in poses:
            continue
        chain[i] = c
        if c not in last:
            s[i] = vt[i] = vr[i] = 0.0
        else:
            k = last[c]
            s[i] = s[k] + float(np.linalg.norm(poses[i][:3, 3] - poses[k][:3, 3]))
            vt[i] = vt[k] + (step_t.get(i, 0.0) if np.isfinite(step_t.get(i, 0.0)) else 0.0)
            vr[i] = vr[k] + (step_r.get(i, 0.0) if np.isfinite(step_r.get(i, 0.0)) else 0.0)
        last[c] = i
    return ChainPath(chain, s, vt, vr, poses)


def _angles(R: NDArray[np.float64]) -> NDArray[np.float64]:
    """Rotation angles (rad) of (..., 3, 3) rotation matrices."""
    tr = np.trace(R, axis1=-2, axis2=-1)
    return np.asarray(np.arccos(np.clip((tr - 1.0) / 2.0, -1.0, 1.0)), np.float64)


def translation_bound(path_m: NDArray[np.float64] | float, var_t: NDArray[np.float64] | float,
                      params: SlamGraphParams) -> NDArray[np.float64]:
    """How far (m) a loop may disagree with a chain stretch of `path_m` metres whose edges'
    translation variances add up to `var_t` (m^2) and still pass the chain gate."""
    return np.asarray(params.gate_floor_m + params.chain_drift_m_per_m * np.asarray(path_m)
                      + params.gate_sigmas * np.sqrt(var_t), np.float64)


def _within(t_err: NDArray[np.float64], r_err: NDArray[np.float64], path_m: NDArray[np.float64],
            var_t: NDArray[np.float64], var_r: NDArray[np.float64], params: SlamGraphParams) -> NDArray[np.bool_]:
    """Errors within the bound of a chain stretch of `path_m` metres and accumulated variances."""
    bound_t = translation_bound(path_m, var_t, params)
    bound_r = (np.radians(params.gate_floor_deg + params.chain_drift_deg_per_m * path_m)
               + params.gate_sigmas * np.sqrt(var_r))
    return np.asarray((t_err <= bound_t) & (r_err <= bound_r), np.bool_)


def _stretch(path: ChainPath, x: Sequence[int], y: Sequence[int]) -> tuple[F64, F64, F64]:
    """(path m, var_t, var_r) of the chain stretches between keyframes x[k] and y[k]."""
    def arr(d: dict[int, float], ids: Sequence[int]) -> F64:
        return np.array([d[i] for i in ids], np.float64)

    return (np.abs(arr(path.s, x) - arr(path.s, y)), np.abs(arr(path.var_t, x) - arr(path.var_t, y)),
            np.abs(arr(path.var_r, x) - arr(path.var_r, y)))


def chain_gate(loops: Sequence[Edge], path: ChainPath, params: SlamGraphParams) -> list[str]:
    """Per loop: "" when it agrees with the chain (or joins two chains: nothing to compare),
    else why it is rejected (`CHAIN`, `NO_CHAIN`)."""
    out = []
    for e in loops:
        if e.a not in path.poses or e.b not in path.poses:
            out.append(NO_CHAIN)
            continue
        if path.chain[e.a] != path.chain[e.b]:
            out.append("")
            continue
        E = invert(e.T_a_b) @ invert(path.poses[e.a]) @ path.poses[e.b]
        ok = _within(np.array([np.linalg.norm(E[:3, 3])]), _angles(E[None, :3, :3]),
                     *_stretch(path, [e.a], [e.b]), params)
        out.append("" if bool(ok[0]) else CHAIN)
    return out


def consistency_matrix(loops: Sequence[Edge], path: ChainPath, params: SlamGraphParams) -> NDArray[np.bool_]:
    """(n, n) symmetric: loops i and j close their cycle through the chain (module docstring).
    Every loop's keyframes must have a chain pose."""
    n = len(loops)
    if n == 0:
        return np.zeros((0, 0), bool)
    A = np.stack([path.poses[e.a] for e in loops])
    B = np.stack([path.poses[e.b] for e in loops])
    L = np.stack([e.T_a_b for e in loops])
    # M_i = A_i L_i B_i^-1: the correction of chain b's frame into chain a's that loop i implies;
    # the cycle of loops i, j is B_i^-1 M_i^-1 M_j B_i (same angle as M_i^-1 M_j)
    M = A @ L @ np.linalg.inv(B)
    Minv = np.linalg.inv(M)
    D = np.einsum("iab,jbc->ijac", Minv, M)
    tB = B[:, :3, 3]
    lever = np.einsum("ijab,ib->ija", D[:, :, :3, :3], tB) + D[:, :, :3, 3] - tB[:, None, :]
    t_err = np.linalg.norm(lever, axis=-1)
    r_err = _angles(D[:, :, :3, :3])
    ca = np.array([path.chain[e.a] for e in loops])
    cb = np.array([path.chain[e.b] for e in loops])
    ia = np.repeat([e.a for e in loops], n)
    ja = np.tile([e.a for e in loops], n)
    ib = np.repeat([e.b for e in loops], n)
    jb = np.tile([e.b for e in loops], n)
    sa, ta, ra = _stretch(path, ia.tolist(), ja.tolist())
    sb, tb, rb = _stretch(path, ib.tolist(), jb.tolist())
    comparable = (ca[:, None] == ca[None, :]) & (cb[:, None] == cb[None, :])
    ok = _within(t_err, r_err, (sa + sb).reshape(n, n), (ta + tb).reshape(n, n), (ra + rb).reshape(n, n),
                 params) | ~comparable
    ok = ok & ok.T
    np.fill_diagonal(ok, True)
    return np.asarray(ok, np.bool_)


def max_clique(adjacency: NDArray[np.bool_]) -> list[int]:
    """A large clique of a symmetric boolean graph (diagonal True), greedily: from a start
    vertex (most neighbours first) add the candidate with the most neighbours among the
    remaining candidates (counts kept up to date as candidates drop out: O(n^2) per start).
    Vertices too poorly connected to beat the best clique found, and members of it (a start
    there grows the same clique again), are not tried as starts. Returns the clique's vertex
    indices, sorted."""
    C = np.asarray(adjacency, bool)
    degree = C.sum(axis=1)
    best: list[int] = []
    in_best = np.zeros(len(C), bool)
    for v in np.argsort(-degree, kind="stable"):
        if degree[v] <= len(best):
            break
        if in_best[v]:
            continue
        clique = [int(v)]
        cand = C[v].copy()
        cand[v] = False
        score = C[:, cand].sum(axis=1)  # each vertex's neighbours among the candidates
        while cand.any():
            idx = np.flatnonzero(cand)
            u = int(idx[np.argmax(score[idx])])
            clique.append(u)
            gone = cand & ~C[u]
            gone[u] = True
            cand &= ~gone
            score -= C[:, gone].sum(axis=1)
        if len(clique) > len(best):
            best = clique
            in_best[:] = False
            in_best[best] = True
    return sorted(best)


def gate_loops(loops: Sequence[Edge], path: ChainPath, params: SlamGraphParams) -> list[str]:
    """Per loop: "" when it passes both checks, else why not (`CHAIN`, `PAIRWISE`, `NO_CHAIN`)."""
    reasons = chain_gate(loops, path, params)
    alive = [i for i, r in enumerate(reasons) if not r]
    C = consistency_matrix([loops[i] for i in alive], path, params)
    keep = {alive[k] for k in max_clique(C)}
    return [r if r else ("" if i in keep else PAIRWISE) for i, r in enumerate(reasons)]
