"""The pose graph: keyframe camera poses, odometry / visual / loop edges, robust optimisation.

Variables are the keyframes' `T_map_camera` (GTSAM `Pose3`); the first keyframe is fixed at
the map frame's pose of it. Odometry and visual edges are known inliers; loop edges are
robust factors under GTSAM's graduated non-convexity (GNC, truncated least squares) with
Levenberg-Marquardt: a loop that the rest of the graph contradicts ends with weight ~0
instead of bending the map, and the result names each loop's final weight.

Before GNC, loops are gated against the chain and against each other
(`pipelines.slam.consistency`, `graph.gate_loops`): a loop that a repeating texture shifted
by one repetition is rejected there, with its reason (`GraphResult.loop_gate`), and GNC runs
over the loops left, from the least-squares solution with them.

Chains (keyframes joined by odometry or visual edges) other than the first keyframe's enter
only through loops: each such chain gets a weak prior on its first keyframe so the problem
stays well posed if the optimiser rejects every loop to it, and a chain whose loops to the
map are all rejected (or that has none) is left out of the map (`GraphResult.dropped`).

With a `LevelFloor` (`pipelines.slam.level`) every keyframe in the map also gets absolute
level and height factors (known inliers, like the odometry and visual edges); the chain gate's
chain solution is solved without them (each chain in its own frame).

The visual edges' covariance (the two-keyframe refinement's) is multiplied by
`graph.visual_covariance_scale` in the optimisation: compared with a simulator's truth their
errors exceed it (whitened errors, `docs/mapping.md`); the chain gate keeps their own.

`reoptimise` solves a result again with the loops it kept and extra factors and variables
(the walls of `pipelines.slam.planes`).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Container, Sequence
from dataclasses import dataclass, field
from typing import Protocol

import gtsam
import numpy as np
from numpy.typing import NDArray

from litevloc.base.geometry import invert
from litevloc.base.params.slam import SlamGraphParams
from litevloc.pipelines.slam.consistency import chain_path, gate_loops
from litevloc.pipelines.slam.level import LevelFloor, level_factors
from litevloc.pipelines.slam.types import F64, Edge


class GraphNode(Protocol):
    """What the optimiser needs of a keyframe (`pipelines.slam.types.Keyframe` has it)."""

    @property
    def id(self) -> int: ...

    @property
    def chain(self) -> int: ...

    @property
    def T_init(self) -> F64: ...


_WEAK_PRIOR_SIGMA = 1e3  # metres and radians: a placeholder prior that any real edge overrides


@dataclass
class GraphResult:
    """Optimised poses of the keyframes in the map (id -> 4x4 T_map_camera), the final GNC
    weight of every loop edge given (same order; 1.0 when no robust solve ran, 0.0 when the
    gate rejected it), the ids of keyframes left out (their chain is not joined to the map by a
    kept loop), and per loop why the gate rejected it ("" = passed; `pipelines.slam.consistency`)."""

    poses: dict[int, F64]
    loop_weights: list[float]
    dropped: list[int] = field(default_factory=list)
    loop_gate: list[str] = field(default_factory=list)


def pose_key(i: int) -> int:
    """The GTSAM key of keyframe `i`'s pose (symbol x_i): other factors on the graph's poses use it."""
    return int(gtsam.symbol("x", i))


def _pose3(T: F64) -> gtsam.Pose3:
    return gtsam.Pose3(gtsam.Rot3(np.asarray(T[:3, :3], float)), np.asarray(T[:3, 3], float))


def _chain_order(keyframes: Sequence[GraphNode], loops: list[Edge]) -> tuple[list[int], dict[int, F64]]:
    """Chains reachable from the first keyframe's through loops (breadth first), and for each
    the transform that places its initial estimates in the first chain's frame (from the
    first loop that reaches it)."""
    links: dict[int, list[Edge]] = {}
    for e in loops:
        ca, cb = keyframes[e.a].chain, keyframes[e.b].chain
        if ca != cb:
            links.setdefault(ca, []).append(e)
            links.setdefault(cb, []).append(e)
    main = keyframes[0].chain
    align: dict[int, F64] = {main: np.eye(4)}
    order = [main]
    todo = deque([main])
    while todo:
        c = todo.popleft()
        for e in links.get(c, []):
            a, b = keyframes[e.a], keyframes[e.b]
            other, known_is_a = (b, True) if a.chain == c else (a, False)
            if other.chain in align:
                continue
            # T_first_a @ T_a_b = T_first_b: place the other chain so that the loop holds
            if known_is_a:
                T_first_b = align[c] @ a.T_init @ e.T_a_b
                align[other.chain] = T_first_b @ invert(b.T_init)
            else:
                T_first_a = align[c] @ b.T_init @ invert(e.T_a_b)
                align[other.chain] = T_first_a @ invert(a.T_init)
            order.append(other.chain)
            todo.append(other.chain)
    return order, align


def _initial(keyframes: Sequence[GraphNode], align: dict[int, F64], T0: F64) -> gtsam.Values:
    init = gtsam.Values()
    for kf in keyframes:
        if kf.chain in align:
            init.insert(pose_key(kf.id), _pose3(T0 @ align[kf.chain] @ kf.T_init))
    return init


def _priors(keyframes: Sequence[GraphNode], chains: list[int], init: gtsam.Values,
            T0: F64) -> gtsam.NonlinearFactorGraph:
    """The first keyframe fixed; a weak prior on the first keyframe of every other chain."""
    graph = gtsam.NonlinearFactorGraph()
    graph.add(gtsam.PriorFactorPose3(pose_key(keyframes[0].id), _pose3(T0 @ keyframes[0].T_init),
                                     gtsam.noiseModel.Isotropic.Sigma(6, 1e-6)))
    firsts: dict[int, GraphNode] = {}
    for kf in keyframes:
        firsts.setdefault(kf.chain, kf)
    for c in chains[1:]:
        kf = firsts[c]
        graph.add(gtsam.PriorFactorPose3(pose_key(kf.id), init.atPose3(pose_key(kf.id)),
                                         gtsam.noiseModel.Isotropic.Sigma(6, _WEAK_PRIOR_SIGMA)))
    return graph


def _between(e: Edge, visual_scale: float = 1.0) -> gtsam.BetweenFactorPose3:
    scale = visual_scale if e.kind == "visual" else 1.0
    noise = gtsam.noiseModel.Gaussian.Covariance(scale * np.asarray(e.covariance, float))
    return gtsam.BetweenFactorPose3(pose_key(e.a), pose_key(e.b), _pose3(e.T_a_b), noise)


def _gnc_weights(graph: gtsam.NonlinearFactorGraph, init: gtsam.Values, robust: list[int],
                 params: SlamGraphParams) -> NDArray[np.float64]:
    """GNC (truncated least squares) weights of every factor; only `robust` rows can lose weight.
    It starts from the odometry and visual edges alone (every loop at weight 0), not from a
    least-squares solution that every loop, wrong ones included, has bent."""
    gp = gtsam.GncLMParams(gtsam.LevenbergMarquardtParams())
    gp.setLossType(gtsam.GncLossType.TLS)
    gp.setKnownInliers([k for k in range(graph.size()) if k not in set(robust)])
    opt = gtsam.GncLMOptimizer(graph, init, gp)
    opt.setInlierCostThresholdsAtProbability(params.inlier_probability)
    opt.optimize()
    return np.asarray(opt.getWeights(), np.float64)


def chain_solution(keyframes: Sequence[GraphNode], edges: list[Edge]) -> dict[int, F64]:
    """Least-squares poses (id -> 4x4) of every keyframe from the odometry and visual edges
    alone, each chain in its own frame (its first keyframe held at its initial estimate)."""
    init = gtsam.Values()
    graph = gtsam.NonlinearFactorGraph()
    first: set[int] = set()
    for kf in keyframes:
        init.insert(pose_key(kf.id), _pose3(kf.T_init))
        if kf.chain not in first:
            first.add(kf.chain)
            graph.add(gtsam.PriorFactorPose3(pose_key(kf.id), _pose3(kf.T_init),
                                             gtsam.noiseModel.Isotropic.Sigma(6, 1e-6)))
    for e in edges:
        if e.kind != "loop":
            graph.add(_between(e))
    values = gtsam.LevenbergMarquardtOptimizer(graph, init).optimize()
    return {kf.id: np.asarray(values.atPose3(pose_key(kf.id)).matrix(), np.float64) for kf in keyframes}


def _gate(keyframes: Sequence[GraphNode], edges: list[Edge], loops: list[Edge], params: SlamGraphParams) -> list[str]:
    if not params.gate_loops or not loops:
        return [""] * len(loops)
    path = chain_path([(kf.id, kf.chain) for kf in keyframes], chain_solution(keyframes, edges), edges)
    return gate_loops(loops, path, params)


def optimise(keyframes: Sequence[GraphNode], edges: list[Edge], T_map_first: F64,
             params: SlamGraphParams, level: LevelFloor | None = None) -> GraphResult:
    """Optimise the keyframe poses (see the module docstring). `edges` of all kinds; loop
    weights come back in the order of the loop edges in `edges`. The poses are the
    least-squares solution over the odometry and visual edges (and the `level` floor's
    factors) and the loops GNC kept."""
    all_loops = [e for e in edges if e.kind == "loop"]
    gate = _gate(keyframes, edges, all_loops, params)
    passed = [e for e, g in zip(all_loops, gate, strict=True) if not g]
    res = _optimise(keyframes, [e for e in edges if e.kind != "loop"] + passed, T_map_first, params,
                    warm=params.gate_loops, level=level)
    it = iter(res.loop_weights)
    res.loop_weights = [0.0 if g else next(it) for g in gate]
    res.loop_gate = gate
    return res


def _least_squares_graph(priors: gtsam.NonlinearFactorGraph, edges: list[Edge], in_map: Container[int],
                         kept_loops: list[Edge], params: SlamGraphParams,
                         floor: gtsam.NonlinearFactorGraph | None) -> gtsam.NonlinearFactorGraph:
    """The final least-squares graph: `priors`, the odometry and visual edges between keyframes
    in the map (visual covariances scaled), the level `floor`'s factors, then the loops kept."""
    graph = priors
    for e in edges:
        if e.kind != "loop" and e.a in in_map and e.b in in_map:
            graph.add(_between(e, params.visual_covariance_scale))
    if floor is not None:
        graph.push_back(floor)
    for e in kept_loops:
        graph.add(_between(e))
    return graph


def _optimise(keyframes: Sequence[GraphNode], edges: list[Edge], T_map_first: F64,
              params: SlamGraphParams, warm: bool, level: LevelFloor | None = None) -> GraphResult:
    """GNC over the loops in `edges`, then least squares over the kept ones; `warm`: GNC starts
    from the least-squares solution with every loop (loops already found consistent)."""
    loops = [e for e in edges if e.kind == "loop"]
    chains, align = _chain_order(keyframes, loops)
    in_map = {kf.id for kf in keyframes if kf.chain in align}
    T0 = np.asarray(T_map_first, np.float64) @ invert(keyframes[0].T_init)
    init = _initial(keyframes, align, T0)
    graph = _priors(keyframes, chains, init, T0)
    loop_rows: list[int | None] = []
    for e in edges:
        usable = e.a in in_map and e.b in in_map
        if e.kind == "loop":
            loop_rows.append(graph.size() if usable else None)
        if usable:
            graph.add(_between(e, params.visual_covariance_scale))
    floor = None if level is None else level_factors(
        level, [(pose_key(kf.id), init.atPose3(pose_key(kf.id)).matrix()) for kf in keyframes if kf.id in in_map])
    if floor is not None:
        graph.push_back(floor)
    robust = [r for r in loop_rows if r is not None]
    start = gtsam.LevenbergMarquardtOptimizer(graph, init).optimize() if (warm and robust) else init
    weights = _gnc_weights(graph, start, robust, params) if robust else np.ones(graph.size())
    loop_weights = [float(weights[r]) if r is not None else 0.0 for r in loop_rows]
    kept_loops = [e for e, w in zip(loops, loop_weights, strict=True) if w > params.kept_weight]
    final = _least_squares_graph(_priors(keyframes, chains, init, T0), edges, in_map, kept_loops, params, floor)
    values = gtsam.LevenbergMarquardtOptimizer(final, init).optimize()
    kept_chains = _joined(keyframes[0].chain, set(align), loops, loop_weights, keyframes, params)
    poses = {kf.id: np.asarray(values.atPose3(pose_key(kf.id)).matrix(), np.float64)
             for kf in keyframes if kf.id in in_map and kf.chain in kept_chains}
    dropped = [kf.id for kf in keyframes if kf.id not in poses]
    return GraphResult(poses, loop_weights, dropped)


def _joined(main: int, candidates: set[int], loops: list[Edge], weights: list[float], keyframes: Sequence[GraphNode],
            params: SlamGraphParams) -> set[int]:
    """Chains joined to `main` through kept loops (a chain kept only by a loop to another
    dropped chain is not joined)."""
    adj: dict[int, set[int]] = {}
    for e, w in zip(loops, weights, strict=True):
        if w <= params.kept_weight:
            continue
        ca, cb = keyframes[e.a].chain, keyframes[e.b].chain
        adj.setdefault(ca, set()).add(cb)
        adj.setdefault(cb, set()).add(ca)
    seen = {main}
    todo = [main]
    while todo:
        c = todo.pop()
        for o in adj.get(c, ()):
            if o not in seen and o in candidates:
                seen.add(o)
                todo.append(o)
    return seen


def reoptimise(keyframes: Sequence[GraphNode], edges: list[Edge], result: GraphResult, T_map_first: F64,
               params: SlamGraphParams, level: LevelFloor | None, extra: gtsam.NonlinearFactorGraph,
               extra_values: gtsam.Values) -> tuple[GraphResult, gtsam.Values]:
    """The least-squares solution of `optimise`'s result again (same keyframes in the map, the
    loops it kept), from its poses, with `extra` factors over the poses (`pose_key`) and the
    variables `extra_values` (their initial values). Returns the result with the new poses and
    the solved values (the extra variables' included)."""
    in_map = result.poses
    loops = [e for e in edges if e.kind == "loop"]
    kept_loops = [e for e, w in zip(loops, result.loop_weights, strict=True) if w > params.kept_weight]
    init = gtsam.Values()
    for kid, T in in_map.items():
        init.insert(pose_key(kid), _pose3(T))
    chains: list[int] = []
    for kf in keyframes:
        if kf.id in in_map and kf.chain not in chains:
            chains.append(kf.chain)
    T0 = np.asarray(T_map_first, np.float64) @ invert(keyframes[0].T_init)
    floor = None if level is None else level_factors(level, [(pose_key(k), T) for k, T in in_map.items()])
    graph = _least_squares_graph(_priors(keyframes, chains, init, T0), edges, in_map.keys(), kept_loops, params,
                                 floor)
    graph.push_back(extra)
    init.insert(extra_values)
    values = gtsam.LevenbergMarquardtOptimizer(graph, init).optimize()
    poses = {k: np.asarray(values.atPose3(pose_key(k)).matrix(), np.float64) for k in in_map}
    return GraphResult(poses, list(result.loop_weights), list(result.dropped), list(result.loop_gate)), values
