"""GL, LL, candidate fallback and the state machine on synthetic geometry (exact truth).

World: random 3D points; each point has a unique descriptor (its id one-hot-ish), so a
matcher that pairs equal descriptors is perfect; tests inject failures explicitly.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
import pytest
from numpy.typing import NDArray

from litevloc.base import geometry as g
from litevloc.base.params.localization import (
    GlobalSearchParams,
    LocalizationParams,
    LocalSearchParams,
    PassesParams,
    PnpParams,
    RepeatParams,
    SecondLookParams,
    SupportParams,
)
from litevloc.pipelines.depth_lookup import depth_at
from litevloc.pipelines.localization.global_search import gl_budget_ms
from litevloc.pipelines.localization.passes import weak
from litevloc.pipelines.localization.prior import Prior
from litevloc.pipelines.localization.query import Query, StageTimer
from litevloc.pipelines.localization.refusals import QueryRefusal
from litevloc.pipelines.localization.results import CandidateAttempt
from litevloc.pipelines.localization.tracking import TrackingState
from litevloc.pipelines.localization.vloc import VisualLocalizer
from litevloc.pipelines.pnp import Refusal
from litevloc.pipelines.topomap.types import NodeFeatures, OccupancyGrid, TopoMap

W, H = 320, 240
K = np.array([[250.0, 0, 160], [0, 250, 120], [0, 0, 1]])
RNG = np.random.default_rng(0)
POINTS = np.column_stack([RNG.uniform(-6, 6, 3000), RNG.uniform(-1.5, 1.5, 3000), RNG.uniform(4, 9, 3000)])
# descriptor: column 0 = point id (match_by_id), then a large random unit vector per point so
# that descriptor similarity (guided matching) is distinctive too
APPEARANCE = RNG.normal(size=(3000, 16))
APPEARANCE *= 1e5 / np.linalg.norm(APPEARANCE, axis=1, keepdims=True)


@dataclass(frozen=True, eq=False)
class Feats:
    keypoints: NDArray[np.float32]
    descriptors: NDArray[np.float32]
    scores: NDArray[np.float32]
    ids: NDArray[np.int64]


def observe(T_world_cam: NDArray[np.float64]) -> tuple[Feats, NDArray[np.float32]]:
    pc = g.transform_points(g.invert(T_world_cam), POINTS)
    front = pc[:, 2] > 0.5
    uv = np.full((len(pc), 2), -1.0)
    uv[front] = g.project(K, pc[front])
    vis = front & (uv[:, 0] > 2) & (uv[:, 0] < W - 3) & (uv[:, 1] > 2) & (uv[:, 1] < H - 3)
    ids = np.nonzero(vis)[0]
    depth = np.full((H, W), np.nan, np.float32)
    for i in ids:
        u, v = np.round(uv[i]).astype(int)
        depth[v - 1 : v + 2, u - 1 : u + 2] = pc[i, 2]
    desc = np.zeros((len(ids), 17), np.float32)
    desc[:, 0] = ids
    desc[:, 1:] = APPEARANCE[ids]
    return Feats(uv[ids].astype(np.float32), desc, np.ones(len(ids), np.float32), ids), depth


def match_by_id(a: Feats, b: NodeFeatures) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    ia = {int(d): k for k, d in enumerate(a.descriptors[:, 0])}
    pairs = [(ia[int(d)], k) for k, d in enumerate(b.descriptors[:, 0]) if int(d) in ia]
    arr = np.array(pairs, dtype=np.int64).reshape(-1, 2)
    return arr[:, 0], arr[:, 1]


def pose(x: float, yaw_deg: float = 0.0) -> NDArray[np.float64]:
    return g.make_T(g.so3_exp(np.array([0, np.radians(yaw_deg), 0])), [x, 0, 0])


def make_map(xs: list[float]) -> TopoMap:
    T = np.stack([pose(x) for x in xs])
    feats, vpr = [], []
    for i, Ti in enumerate(T):
        f, _ = observe(Ti)
        feats.append(NodeFeatures(f.keypoints, f.descriptors, f.scores, (W, H)))
        v = np.zeros(len(xs), np.float32)
        v[i] = 1
        vpr.append(v)
    n = len(xs)
    edges = np.array([(i, i + 1) for i in range(n - 1)], np.int64).reshape(-1, 2)
    grid = OccupancyGrid(np.zeros((2, 2), np.uint8), np.zeros(2), 1.0, np.array([0, -1.0, 0]), np.eye(3)[[0, 2]])
    return TopoMap(T, np.stack([K] * n), np.array([[W, H]] * n, np.int32), np.arange(n, dtype=np.int64),
                   np.arange(n, dtype=np.int64), np.stack(vpr), feats, [b""] * n, edges, np.full(n - 1, 100, np.int32),
                   np.ones(n - 1, np.float32), edges, np.ones(n - 1, np.float32), grid)


class Scene:
    """Injected callables whose output is set per query (the 'camera')."""

    def __init__(self, topomap: TopoMap) -> None:
        self.map = topomap
        self.current: Feats | None = None
        self.vpr = np.zeros(topomap.n_nodes, np.float32)
        self.broken_nodes: set[int] = set()

    def look(self, T: NDArray[np.float64], vpr_best: int) -> NDArray[np.float32]:
        self.current, depth = observe(T)
        self.vpr = np.full(self.map.n_nodes, 0.1, np.float32)
        self.vpr[vpr_best] = 1.0
        return depth

    def extract(self, _img: NDArray[np.uint8]) -> Feats:
        assert self.current is not None
        return self.current

    def describe(self, _img: NDArray[np.uint8]) -> NDArray[np.float32]:
        return self.vpr / np.linalg.norm(self.vpr)

    def match(self, a: Feats, b: NodeFeatures) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        node = next(i for i, f in enumerate(self.map.features) if f is b)
        if node in self.broken_nodes:  # e.g. a changed scene: matches are garbage
            rng = np.random.default_rng(node)
            return rng.integers(0, len(a.keypoints), 200), rng.integers(0, len(b.keypoints), 200)
        return match_by_id(a, b)


IMG = np.zeros((H, W, 3), np.uint8)
# (a broken node is modelled by the matcher's output: LL matching guided by a fresh prior,
# which would not call it, is off here and tested on its own below)
# no full-resolution second look here (tests/pipelines/localization/test_second_look.py)
PARAMS = LocalizationParams(pnp=PnpParams(min_inliers=30), global_search=GlobalSearchParams(top_k=3),
                            local_search=LocalSearchParams(guided_min_matches=0),
                            second_look=SecondLookParams(candidates=0))


def test_global_localization_exact() -> None:
    m = make_map([0.0, 1.0, 2.0, 3.0])
    s = Scene(m)
    loc = VisualLocalizer(m, PARAMS, s.extract, s.describe, s.match)
    T_true = pose(1.3, 5.0)
    depth = s.look(T_true, vpr_best=1)
    r = loc.localize_global(0, IMG, depth, K)
    assert r.accepted and r.ref_node in (1, 2) and r.mode == "global"  # most inliers among the top-3 wins
    dt, dr = g.relative_pose_error(r.T_map_camera, T_true)
    assert dt < 0.005 and dr < 0.2
    assert {"extract", "vpr", "match", "pnp", "total"} <= set(r.timings_ms)


def test_global_reports_not_localized_instead_of_guessing() -> None:
    m = make_map([0.0, 1.0, 2.0])
    s = Scene(m)
    s.broken_nodes = {0, 1, 2}
    loc = VisualLocalizer(m, PARAMS, s.extract, s.describe, s.match)
    r = loc.localize_global(0, IMG, s.look(pose(1.0), 1), K)
    assert not r.accepted and r.T_map_camera is None and "not localized" in r.reason
    assert len(r.attempts) == 3


def test_local_candidate_fallback() -> None:
    m = make_map([0.0, 1.0, 2.0, 3.0])
    s = Scene(m)
    loc = VisualLocalizer(m, PARAMS, s.extract, s.describe, s.match)
    T_true = pose(2.1)
    depth = s.look(T_true, vpr_best=2)
    s.broken_nodes = {2}  # the most similar candidate fails verification...
    r = loc.localize_local(0, IMG, depth, K, Prior(pose(2.3), fused=False))
    assert r.accepted and r.ref_node != 2  # ...and hands over to the next one
    assert r.attempts[0].node == 2 and r.attempts[0].reason != "ok"
    assert g.relative_pose_error(r.T_map_camera, T_true)[0] < 0.005
    far = loc.localize_local(0, IMG, depth, K, Prior(pose(50.0), fused=False))
    assert far.refusal is QueryRefusal.NO_NODE_NEAR_PRIOR and far.reason == "no map node near the prior"
    assert not far.attempts
    s.broken_nodes = {0, 1, 2, 3}
    none = loc.localize_local(0, IMG, depth, K, Prior(pose(2.3), fused=False))
    assert none.refusal is QueryRefusal.NO_CANDIDATE and none.reason == "not localized: no candidate verified"


def test_state_machine_transitions() -> None:
    m = make_map([0.0, 1.0, 2.0, 3.0])
    s = Scene(m)
    loc = VisualLocalizer(m, PARAMS, s.extract, s.describe, s.match)
    assert loc.tracker.state == TrackingState.INIT
    r = loc.process(1, IMG, s.look(pose(0.5), 0), K)
    assert r.accepted and r.mode == "global" and loc.tracker.state == TrackingState.TRACKING
    r = loc.process(2, IMG, s.look(pose(0.8), 1), K)
    assert r.accepted and r.mode == "local"
    s.broken_nodes = {0, 1, 2, 3}
    for t in range(3, 6):
        r = loc.process(t, IMG, s.look(pose(0.9), 1), K)
        assert not r.accepted and r.mode == "local"
    assert loc.tracker.state == TrackingState.LOST
    s.broken_nodes = set()
    r = loc.process(6, IMG, s.look(pose(2.0), 2), K)
    assert r.accepted and r.mode == "global" and loc.tracker.state == TrackingState.TRACKING
    states = [(tr.from_state.value, tr.to_state.value) for tr in loc.tracker.transitions]
    assert states == [("INIT", "GLOBAL"), ("GLOBAL", "TRACKING"), ("TRACKING", "LOST"), ("LOST", "GLOBAL"),
                      ("GLOBAL", "TRACKING")]
    assert "3 consecutive LL failures" in loc.tracker.transitions[2].reason
    # A prior far from every node sends the machine back to GL.
    # The GL pose lies outside that prior's gate: held until a later frame repeats it.
    r = loc.process(7, IMG, s.look(pose(3.0), 3), K, Prior(pose(50.0)))
    assert r.mode == "global" and not r.accepted and "held until a later frame repeats it" in r.reason
    r = loc.process(8, IMG, s.look(pose(3.0), 3), K, Prior(pose(50.0)))
    assert r.mode == "global" and r.accepted and "repeats the pose held" in r.stop_reason


def test_missing_depth_is_an_error() -> None:
    m = make_map([0.0, 1.0])
    s = Scene(m)
    loc = VisualLocalizer(m, PARAMS, s.extract, s.describe, s.match)
    s.look(pose(0.0), 0)
    with pytest.raises(ValueError, match="depth"):
        loc.localize_global(0, IMG, None, K)


def test_joint_refinement_uses_several_keyframes_and_matches_each_once() -> None:
    m = make_map([0.0, 1.0, 2.0, 3.0])
    s = Scene(m)
    calls: list[int] = []

    def counting_match(a: Feats, b: NodeFeatures) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        calls.append(next(i for i, f in enumerate(m.features) if f is b))
        return s.match(a, b)

    # candidates in VPR order (the re-ordering by mutual neighbours has its own test)
    loc = VisualLocalizer(m, replace(PARAMS, global_search=replace(PARAMS.global_search, rerank=False)), s.extract,
                          s.describe, counting_match)
    T_true = pose(1.3, 5.0)
    r = loc.localize_global(0, IMG, s.look(T_true, vpr_best=1), K)
    assert r.accepted and len(r.keyframes) >= 2 and r.ref_node == 1  # the first VPR candidate that passes
    assert "passed the joint check" in r.stop_reason and "refine" in r.timings_ms
    assert len(calls) == len(set(calls))  # verification and refinement share the matches
    dt, dr = g.relative_pose_error(r.T_map_camera, T_true)
    assert dt < 0.005 and dr < 0.2
    assert r.covariance is not None and r.covariance.shape == (6, 6)


def test_gl_time_budget_stops_the_search_and_says_so() -> None:
    m = make_map([0.0, 1.0, 2.0])
    s = Scene(m)
    s.broken_nodes = {0, 1, 2}
    slow = replace(PARAMS, local_search=replace(PARAMS.local_search, guided_min_matches=60),
                   global_search=replace(PARAMS.global_search, time_budget_ms=1e-6))
    loc = VisualLocalizer(m, slow, s.extract, s.describe, s.match)
    r = loc.localize_global(0, IMG, s.look(pose(1.0), 1), K)
    # one candidate is always verified; the next would overrun the budget
    assert not r.accepted and "time budget" in r.stop_reason and len(r.attempts) == 1
    assert "after 1 of 3 candidates" in r.stop_reason
    loc = VisualLocalizer(m, PARAMS, s.extract, s.describe, s.match)
    r = loc.localize_global(0, IMG, s.look(pose(1.0), 1), K)
    assert not r.accepted and r.stop_reason == "all 3 VPR candidates tried" and len(r.attempts) == 3
    with pytest.raises(ValueError):
        LocalizationParams(global_search=GlobalSearchParams(time_budget_ms=-1))


def test_gl_candidates_are_tried_in_order_of_shared_mutual_neighbours() -> None:
    m = make_map([0.0, 1.0, 2.0, 3.0])
    s = Scene(m)
    # VPR ranks node 0 first, but the live frame shares its features with node 2
    depth = s.look(pose(2.0), vpr_best=0)
    off = VisualLocalizer(m, replace(PARAMS, global_search=replace(PARAMS.global_search, rerank=False)), s.extract,
                          s.describe, s.match)
    r = off.localize_global(0, IMG, depth, K)
    assert r.attempts[0].node == 0
    on = VisualLocalizer(m, PARAMS, s.extract, s.describe, s.match)
    r = on.localize_global(0, IMG, depth, K)
    assert r.accepted and r.ref_node == 2 and [a.node for a in r.attempts] == [2] and "rerank" in r.timings_ms
    # the nearer the keyframe, the more it shares: node 2 (0 m), 3 (1 m), 0 (2 m)
    assert on.global_search._rerank(on.params, np.array([0, 3, 2]), _query(on, depth)).tolist() == [2, 3, 0]
    with pytest.raises(ValueError, match="rerank_min_similarity"):
        LocalizationParams(global_search=GlobalSearchParams(rerank_min_similarity=1.5))


def _query(loc: VisualLocalizer, depth: NDArray[np.float32]) -> Query:
    q, _ = loc.verifier.query(IMG, depth, K, loc.params, StageTimer())
    return q


def test_recovering_gl_is_bounded_by_the_ll_cost() -> None:
    m = make_map([0.0, 1.0, 2.0, 3.0])
    s = Scene(m)
    loc = VisualLocalizer(m, PARAMS, s.extract, s.describe, s.match)
    assert gl_budget_ms(loc.params, loc.tracker.ll_wall_ms) == 0.0  # no LL cost known: no bound
    # the GL query's own front end + one candidate
    assert gl_budget_ms(loc.params, loc.tracker.ll_wall_ms, nominal_ll_ms=150.0) == 300.0
    assert loc.process(1, IMG, s.look(pose(0.5), 0), K).accepted
    assert not loc.tracker.ll_wall_ms
    assert loc.process(2, IMG, s.look(pose(0.8), 1), K).mode == "local"
    assert len(loc.tracker.ll_wall_ms) == 1 and loc.tracker.ll_wall_ms[0] > 0
    assert gl_budget_ms(loc.params, loc.tracker.ll_wall_ms) == pytest.approx(2.0 * loc.tracker.ll_wall_ms[0])
    s.broken_nodes = {0, 1, 2, 3}
    for t in range(3, 6):
        loc.process(t, IMG, s.look(pose(0.9), 1), K)
    assert loc.tracker.state == TrackingState.LOST
    loc.tracker.ll_wall_ms.extend([1e-6] * 60)  # LL queries that cost nothing: one candidate per GL query
    r = loc.process(6, IMG, s.look(pose(0.9), 1), K)
    assert r.mode == "global" and len(r.attempts) == 1 and "would be overrun" in r.stop_reason
    s.broken_nodes = set()
    r = loc.process(7, IMG, s.look(pose(2.0), 2), K)
    assert r.accepted and r.mode == "global" and loc.tracker.state == TrackingState.TRACKING
    # the median of the last LL queries sets the bound; the configured budget and the LL bound:
    # the smaller wins; ratio 0 turns the bound off
    loc.tracker.ll_wall_ms.extend([100.0] * 30 + [1000.0] * 20)
    assert gl_budget_ms(loc.params, loc.tracker.ll_wall_ms) == 200.0
    assert gl_budget_ms(loc.params, loc.tracker.ll_wall_ms, nominal_ll_ms=80.0) == 160.0  # the lower of the two
    assert gl_budget_ms(replace(PARAMS, global_search=replace(PARAMS.global_search, time_budget_ms=50.0)), []) == 50.0
    both = VisualLocalizer(m, replace(PARAMS, global_search=replace(PARAMS.global_search, time_budget_ms=500.0)),
                           s.extract, s.describe, s.match)
    both.tracker.ll_wall_ms.append(100.0)
    assert gl_budget_ms(both.params, both.tracker.ll_wall_ms) == 200.0
    free = VisualLocalizer(m, replace(PARAMS, global_search=replace(PARAMS.global_search, lost_cost_ratio=0.0)),
                           s.extract, s.describe, s.match)
    free.tracker.ll_wall_ms.append(100.0)
    assert gl_budget_ms(free.params, free.tracker.ll_wall_ms) == 0.0
    with pytest.raises(ValueError, match="lost_cost_ratio"):
        LocalizationParams(global_search=GlobalSearchParams(lost_cost_ratio=-1))


def test_accepted_results_carry_the_matched_pixels_with_inliers_marked() -> None:
    """For the live view: the matches with the reference keyframe, inliers under the accepted
    pose; a garbage-matching keyframe's matches are outliers, a rejected result carries none."""
    m = make_map([0.0, 1.0, 2.0, 3.0])
    s = Scene(m)
    loc = VisualLocalizer(m, PARAMS, s.extract, s.describe, s.match)
    r = loc.localize_global(0, IMG, s.look(pose(1.3, 5.0), vpr_best=1), K)
    assert r.accepted and r.matches is not None and r.matches.keyframe == r.ref_node
    mp = r.matches
    assert mp.live_px.shape == mp.keyframe_px.shape == (len(mp.inlier), 2) and len(mp.inlier) >= 30
    ref_attempt = next(a for a in r.attempts if a.node == r.ref_node)
    # the same matches PnP verified; inliers under the refined pose agree with PnP's (some
    # synthetic points have no depth and are outliers in both)
    assert len(mp.inlier) == ref_attempt.matches
    assert abs(int(mp.inlier.sum()) - ref_attempt.inliers) <= 0.02 * len(mp.inlier)
    assert loc.verifier.matched_pixels(None, r.ref_node, r.T_map_camera) is None
    shifted = r.T_map_camera @ pose(0.5, 20.0)  # a pose 0.5 m / 20 deg off: (nearly) nothing reprojects
    q, _ = loc.verifier.query(IMG, s.look(pose(1.3, 5.0), vpr_best=1), K, loc.params, StageTimer())
    q_res = loc.verifier.matched_pixels(q, r.ref_node, shifted)
    assert q_res is not None and q_res.inlier.mean() < 0.05
    s2 = Scene(m)
    s2.broken_nodes = {0, 1, 2, 3}
    bad = VisualLocalizer(m, PARAMS, s2.extract, s2.describe, s2.match).localize_global(
        0, IMG, s2.look(pose(1.3, 5.0), vpr_best=1), K)
    assert not bad.accepted and bad.matches is None


def test_place_seen_by_one_keyframe_is_provisional_until_a_prior_agrees() -> None:
    """A one-keyframe map: PnP verifies the place, no second keyframe can confirm it. GL returns
    a provisional pose (a fusion vote), not a fix; with a prior that agrees, GLOBAL accepts it."""
    from dataclasses import replace

    m = make_map([0.0])
    s = Scene(m)
    # distinctiveness standing in for the second keyframe is off here (test_distinct.py tests it)
    single = replace(PARAMS, confirm=replace(PARAMS.confirm, gl_single_distinct_ratio=0.0))
    loc = VisualLocalizer(m, single, s.extract, s.describe, s.match)
    T_true = pose(0.3, 5.0)
    depth = s.look(T_true, vpr_best=0)
    r = loc.localize_global(0, IMG, depth, K)
    assert not r.accepted and r.T_map_camera is None and r.provisional is not None
    assert r.provisional.node == 0 and r.provisional.n_inliers >= PARAMS.global_search.vote_min_inliers
    dt, dr = g.relative_pose_error(r.provisional.T_map_camera, T_true)
    assert dt < 0.01 and dr < 0.5
    assert r.provisional.covariance.shape == (6, 6)
    # a prior 2 m away (beyond the 0.75 m gate): still not a fix
    far = loc.localize_global(0, IMG, depth, K, Prior(pose(2.3, 5.0)))
    assert not far.accepted and far.provisional is not None
    # a close prior that rests on a fix long ago (its growth beyond what may stand in for a
    # second keyframe): not a fix either
    stale = loc.localize_global(0, IMG, depth, K, Prior(pose(0.4, 3.0), 60.0))
    assert not stale.accepted and stale.provisional is not None
    assert loc.localize_global(0, IMG, depth, K, Prior(pose(0.4, 3.0), 2.0)).accepted
    # the state machine: GLOBAL without a prior stays GLOBAL, with an agreeing prior -> TRACKING
    assert not loc.process(0, IMG, depth, K).accepted and loc.tracker.state == TrackingState.GLOBAL
    acc = loc.process(1, IMG, depth, K, Prior(pose(0.4, 3.0)))
    assert acc.accepted and acc.provisional is None and loc.tracker.state == TrackingState.TRACKING
    assert "agrees with the prior" in acc.stop_reason
    dt, _ = g.relative_pose_error(acc.T_map_camera, T_true)
    assert dt < 0.01
    # too few inliers for a vote, or votes disabled: nothing provisional
    votes = PARAMS.global_search
    for p in (replace(single, global_search=replace(votes, vote_min_inliers=0)),
              replace(single, global_search=replace(votes, vote_min_inliers=100_000))):
        r0 = VisualLocalizer(m, p, s.extract, s.describe, s.match).localize_global(0, IMG, depth, K, Prior(pose(0.3)))
        assert not r0.accepted and r0.provisional is None
    with pytest.raises(ValueError, match="vote_min_inliers"):
        LocalizationParams(global_search=GlobalSearchParams(vote_min_inliers=-1))


def test_fused_prior_gate_grows_with_odometry_drift_not_speed() -> None:
    """A prior 1.5 m from the truth, 5 s since its fix: as the last VLoc pose (top speed 1.5 m/s)
    the gate covers it; as a fused prior (odometry drift, 0.1 m/s) it does not."""
    m = make_map([0.0, 1.0, 2.0, 3.0])
    s = Scene(m)
    loc = VisualLocalizer(m, PARAMS, s.extract, s.describe, s.match)
    depth = s.look(pose(2.1), vpr_best=2)
    assert loc.localize_local(0, IMG, depth, K, Prior(pose(0.6), 5.0, fused=False)).accepted
    r = loc.localize_local(0, IMG, depth, K, Prior(pose(0.6), 5.0, fused=True))
    assert not r.accepted and all("inconsistent with the prior" in a.reason for a in r.attempts if a.inliers)
    assert loc.localize_local(0, IMG, depth, K, Prior(pose(1.6), 5.0, fused=True)).accepted


def test_fused_prior_gate_narrows_to_fusions_covariance() -> None:
    """A fused prior 0.5 m along x from the truth, 4 s old (age gate 0.25 + 0.4 m covers it):
    fusion's covariance says 5 cm along x, so the gate toward the pose is 0.25 + 3 x 0.05 m and
    refuses it; 30 cm along x (or an isotropic 30 cm sigma) lets it in again."""
    m = make_map([0.0, 1.0, 2.0, 3.0])
    s = Scene(m)
    loc = VisualLocalizer(m, PARAMS, s.extract, s.describe, s.match)
    depth = s.look(pose(2.1), vpr_best=2)
    prior = pose(1.6)
    assert loc.localize_local(0, IMG, depth, K, Prior(prior, 4.0, fused=True)).accepted
    tight_x = np.diag([0.05**2, 0.3**2, 0.3**2])
    r = loc.localize_local(0, IMG, depth, K, Prior(prior, 4.0, fused=True, cov=tight_x))
    assert not r.accepted and any("> 0.40 m" in a.reason for a in r.attempts if a.inliers)
    tight_y = np.diag([0.3**2, 0.05**2, 0.05**2])
    assert loc.localize_local(0, IMG, depth, K, Prior(prior, 4.0, fused=True, cov=tight_y)).accepted
    # the state machine hands the covariance on and checks it
    with pytest.raises(ValueError, match="prior_cov"):
        loc.process(0, IMG, depth, K, Prior(prior, 4.0, cov=np.eye(2)))


def test_gl_refuses_a_pose_resting_on_the_floor_alone(monkeypatch: pytest.MonkeyPatch) -> None:
    """Every point on one horizontal plane (the map's up is -y here): floor tiles repeat, so GL
    refuses the pose with the reason; the same scene with the check off is accepted (scenes with
    height pass the check: the other tests run with its default)."""
    import sys

    mod = sys.modules[__name__]
    flat = POINTS.copy()
    flat[:, 1] = 1.4  # 1.4 m below the cameras (y down)
    monkeypatch.setattr(mod, "POINTS", flat)
    m = make_map([0.0, 1.0, 2.0, 3.0])
    s = Scene(m)
    depth = s.look(pose(1.1), vpr_best=1)
    loc = VisualLocalizer(m, PARAMS, s.extract, s.describe, s.match)
    res = loc.localize_global(0, IMG, depth, K)
    assert not res.accepted and res.provisional is None
    assert any("one horizontal plane" in a.reason for a in res.attempts), res.attempts
    off = VisualLocalizer(m, replace(PARAMS, local_search=replace(PARAMS.local_search, guided_min_matches=60),
                                     support=replace(PARAMS.support, min_height_m=0.0, min_off_layer_inliers=0)),
                          s.extract, s.describe, s.match)
    res = off.localize_global(0, IMG, depth, K)
    assert res.accepted and res.T_map_camera is not None
    assert np.linalg.norm(res.T_map_camera[:3, 3] - pose(1.1)[:3, 3]) < 0.02


def test_gl_refuses_a_pose_resting_on_floor_and_ceiling_alone(monkeypatch: pytest.MonkeyPatch) -> None:
    """Every point on the floor or the ceiling (they span 2.6 m of height, so the height-span check
    passes): a corridor's tiles above and below repeat, so GL refuses the pose; with the check off
    the same scene is accepted."""
    import sys

    mod = sys.modules[__name__]
    two = POINTS.copy()
    two[:, 1] = np.where(np.arange(len(two)) % 2 == 0, 1.4, -1.2)  # floor 1.4 m below, ceiling 1.2 m above (y down)
    monkeypatch.setattr(mod, "POINTS", two)
    m = make_map([0.0, 1.0, 2.0, 3.0])
    s = Scene(m)
    depth = s.look(pose(1.1), vpr_best=1)
    res = VisualLocalizer(m, PARAMS, s.extract, s.describe, s.match).localize_global(0, IMG, depth, K)
    assert not res.accepted and res.provisional is None
    assert any("floor and ceiling only" in a.reason for a in res.attempts), res.attempts
    off = replace(PARAMS, support=replace(PARAMS.support, min_off_layer_inliers=0))
    res = VisualLocalizer(m, off, s.extract, s.describe, s.match).localize_global(0, IMG, depth, K)
    assert res.accepted and res.T_map_camera is not None
    assert np.linalg.norm(res.T_map_camera[:3, 3] - pose(1.1)[:3, 3]) < 0.02


def test_support_height_spread_parameter_is_validated() -> None:
    with pytest.raises(ValueError, match="min_height_m"):
        LocalizationParams(support=SupportParams(min_height_m=-0.1))


def test_local_matching_guided_by_a_fresh_prior() -> None:
    """With a fresh prior LL matches by projecting with it (no matcher call); a prior too far
    off for the guided matches falls back to the matcher; with the option off the matcher runs."""
    m = make_map([0.0, 1.0, 2.0, 3.0])
    s = Scene(m)
    calls = [0]

    def counting(a: Feats, b: NodeFeatures) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        calls[0] += 1
        return s.match(a, b)

    guided = replace(PARAMS, local_search=replace(PARAMS.local_search, guided_min_matches=60))
    loc = VisualLocalizer(m, guided, s.extract, s.describe, counting)
    T_true = pose(2.1, 3.0)
    depth = s.look(T_true, vpr_best=2)
    near = T_true.copy()
    near[:3, 3] += [0.01, 0.0, 0.01]
    r = loc.localize_local(0, IMG, depth, K, Prior(near, fused=False))
    assert r.accepted and calls[0] == 0 and "guided_match" in r.timings_ms
    assert g.relative_pose_error(r.T_map_camera, T_true)[0] < 0.005
    far = pose(2.1 + 0.15, 3.0)  # 15 cm off: projections land ~5-10 px away at 4-9 m depth ...
    far[:3, :3] = g.so3_exp(np.array([0, np.radians(8.0), 0]))  # ... and 5 deg of yaw: ~20 px
    r = loc.localize_local(0, IMG, depth, K, Prior(far, fused=False))
    assert r.accepted and calls[0] >= 1  # the matcher's matches
    assert g.relative_pose_error(r.T_map_camera, T_true)[0] < 0.005
    calls[0] = 0
    off = VisualLocalizer(m, PARAMS, s.extract, s.describe, counting)
    r = off.localize_local(0, IMG, depth, K, Prior(near, fused=False))
    assert r.accepted and calls[0] >= 1


def test_gl_pose_outside_the_prior_gate_is_held_until_a_later_frame_repeats_it() -> None:
    """A GL pose far from the fused prior is not accepted on one frame: the next GL pose must
    repeat it once carried over by the prior's own motion (the odometry) between the frames.
    One that lands elsewhere replaces the held pose; one inside the gate is accepted at once."""
    from dataclasses import replace

    m = make_map([0.0, 1.0, 2.0, 3.0])
    s = Scene(m)
    loc = VisualLocalizer(m, PARAMS, s.extract, s.describe, s.match)
    sec = 1_000_000_000
    # the prior is 1.6 m off (a 10 s old fix: gate 0.25 + 1.0 m); the robot moves +0.3 m
    r = loc.process(1 * sec, IMG, s.look(pose(1.0), 1), K, Prior(pose(2.6), 10.0))
    assert not r.accepted and r.T_map_camera is None and r.covariance is None
    assert "1.60 m" in r.reason and "outside its gate (1.25 m" in r.reason and loc.tracker.state == TrackingState.GLOBAL
    # the next GL pose lands 1.3 m from where the held one has gone (to 1.3 m): not a repeat;
    # it is held in its place
    r = loc.process(2 * sec, IMG, s.look(pose(0.0), 0), K, Prior(pose(2.9), 11.0))
    assert not r.accepted and loc.tracker.held is not None and loc.tracker.held.t_ns == 2 * sec
    # a repeat of the held pose (the robot moved +0.3 m, and so did the prior): accepted
    r = loc.process(3 * sec, IMG, s.look(pose(0.3), 0), K, Prior(pose(3.2), 12.0))
    assert r.accepted and loc.tracker.state == TrackingState.TRACKING
    assert "repeats the pose held 1.00 s" in r.stop_reason
    assert g.relative_pose_error(r.T_map_camera, pose(0.3))[0] < 0.01 and loc.tracker.held is None
    # a pose inside the gate of a fresh prior needs no repeat; inside the gate of a stale prior
    # (10 s past its fix: beyond the 7.5 s a prior may stand in for a second view) it does
    fresh = VisualLocalizer(m, PARAMS, s.extract, s.describe, s.match)
    assert fresh.process(1, IMG, s.look(pose(1.0), 1), K, Prior(pose(1.2), 0.0)).accepted
    stale = VisualLocalizer(m, PARAMS, s.extract, s.describe, s.match)
    r = stale.process(1 * sec, IMG, s.look(pose(1.0), 1), K, Prior(pose(1.2), 10.0))
    assert not r.accepted and "the prior is 10.0 s past its last fix, too old to confirm it" in r.reason
    assert stale.process(2 * sec, IMG, s.look(pose(1.2), 1), K, Prior(pose(1.4), 11.0)).accepted
    # at the window's end, up to the clock's jitter (5 frames of a 1 Hz clock that runs 5 ns
    # long per frame): still a repeat
    edge = VisualLocalizer(m, PARAMS, s.extract, s.describe, s.match)
    assert not edge.process(0, IMG, s.look(pose(1.0), 1), K, Prior(pose(3.0))).accepted
    r = edge.process(5 * sec + 25, IMG, s.look(pose(1.0), 1), K, Prior(pose(3.0)))
    assert r.accepted and "repeats the pose held 5.00 s" in r.stop_reason
    # too late for a repeat after the robot moved (0.3 m, and so did the prior): held again instead
    late = VisualLocalizer(m, PARAMS, s.extract, s.describe, s.match)
    assert not late.process(0, IMG, s.look(pose(1.0), 1), K, Prior(pose(3.0))).accepted
    assert not late.process(6 * sec, IMG, s.look(pose(1.3), 1), K, Prior(pose(3.3))).accepted
    # a robot at rest (the prior still, up to its 0.1 m) may wait any time for the repeat (slow GL under load)
    rest = VisualLocalizer(m, PARAMS, s.extract, s.describe, s.match)
    assert not rest.process(0, IMG, s.look(pose(1.0), 1), K, Prior(pose(3.0))).accepted
    r = rest.process(40 * sec, IMG, s.look(pose(1.05), 1), K, Prior(pose(3.05)))
    assert r.accepted and "repeats the pose held 40.00 s" in r.stop_reason
    # ... but not a pose that moved where the prior did not
    rest = VisualLocalizer(m, PARAMS, s.extract, s.describe, s.match)
    assert not rest.process(0, IMG, s.look(pose(1.0), 1), K, Prior(pose(3.0))).accepted
    assert not rest.process(40 * sec, IMG, s.look(pose(1.8), 1), K, Prior(pose(3.0))).accepted
    # off: accepted at once, as before
    off = VisualLocalizer(m, replace(PARAMS, repeat=replace(PARAMS.repeat, within_s=0.0)), s.extract, s.describe,
                          s.match)
    assert off.process(0, IMG, s.look(pose(1.0), 1), K, Prior(pose(3.0))).accepted
    with pytest.raises(ValueError, match=r"within_s must be a finite number in \[0, inf\), got -1\.0"):
        LocalizationParams(repeat=RepeatParams(within_s=-1.0))
    with pytest.raises(ValueError, match=r"deg must be a finite number in \(0, 180\], got 0\.0"):
        LocalizationParams(repeat=RepeatParams(deg=0.0))
    with pytest.raises(ValueError, match=r"within_m must be a finite number in \[0, inf\), got -0\.1"):
        LocalizationParams(repeat=RepeatParams(within_m=-0.1))


def _aliased_map() -> TopoMap:
    """Keyframes at x = 0, 1, 2, 10, 11 whose last two see exactly what the first two see:
    a corridor that repeats itself 10 m on (the copies' features are the originals')."""
    m = make_map([0.0, 1.0, 2.0, 10.0, 11.0])
    for copy, original in ((3, 0), (4, 1)):
        f = m.features[original]
        m.features[copy] = NodeFeatures(f.keypoints.copy(), f.descriptors.copy(), f.scores.copy(), f.image_size)
    return m


def test_gl_pose_at_a_copy_of_the_place_gives_way_to_the_priors_place() -> None:
    """In a place that repeats 10 m on, GL verifies the copy first (its VPR is best); with a
    stale fused prior at the true place, LL at the prior's place verifies too and wins (held,
    then repeated, as any pose with a stale prior); without the check the copy is accepted
    once repeated, 10 m off. A prior whose place does not verify leaves GL's pose held."""
    sec = 1_000_000_000
    m = _aliased_map()
    s = Scene(m)

    def look_copies_first(T: NDArray[np.float64]) -> NDArray[np.float32]:
        depth = s.look(T, vpr_best=3)
        s.vpr[[3, 4, 0, 1]] = [1.0, 1.0, 0.5, 0.5]  # the copies retrieved first, the originals next
        return depth

    truth = [pose(0.3), pose(0.6)]
    for check, want_x in ((True, 0.0), (False, 10.0)):
        loc = VisualLocalizer(m, replace(PARAMS, global_search=replace(PARAMS.global_search, check_prior_place=check)),
                              s.extract, s.describe, s.match)
        first = loc.process(1 * sec, IMG, look_copies_first(truth[0]), K, Prior(pose(0.35), 10.0))
        assert not first.accepted and "held until a later frame repeats it" in first.reason
        r = loc.process(2 * sec, IMG, look_copies_first(truth[1]), K, Prior(pose(0.65), 11.0))
        assert r.accepted and "repeats the pose held" in r.stop_reason
        dt, _ = g.relative_pose_error(r.T_map_camera, g.make_T(np.eye(3), [want_x, 0, 0]) @ truth[1])
        assert dt < 0.01, (check, r.T_map_camera[:3, 3])
        if check:
            assert r.mode == "local" and r.ref_node in (0, 1)
            assert "lay 9.95 m from the prior" in r.stop_reason and "the prior's place verified" in r.stop_reason
    # the prior at x = 2 (its place, node 2, sees the live view from a pose outside the gate): GL's pose held
    loc = VisualLocalizer(m, PARAMS, s.extract, s.describe, s.match)
    r = loc.process(1 * sec, IMG, look_copies_first(pose(0.3)), K, Prior(pose(2.0), 10.0))
    assert not r.accepted and loc.tracker.held is not None and loc.tracker.held.T_map_camera[0, 3] > 9.0


def test_a_copy_outside_the_gate_does_not_displace_a_held_pose_inside_it() -> None:
    """In the repeating place, frames alternate: one where the prior's place verifies (a pose
    inside the gate, held: the prior is stale), one where only the copy 10 m on does. The copy
    is refused while the held pose awaits its repeat, so the third frame repeats it; after the
    repeat window a copy is held as any pose outside the gate."""
    sec = 1_000_000_000
    m = _aliased_map()
    s = Scene(m)

    def look(x: float, originals_fail: bool) -> NDArray[np.float32]:
        depth = s.look(pose(x), vpr_best=3)
        s.vpr[[3, 4, 0, 1]] = [1.0, 1.0, 0.5, 0.5]
        s.broken_nodes = {0, 1, 2} if originals_fail else set()
        return depth

    loc = VisualLocalizer(m, PARAMS, s.extract, s.describe, s.match)
    r = loc.process(1 * sec, IMG, look(0.3, False), K, Prior(pose(0.35), 10.0))
    assert not r.accepted and loc.tracker.held is not None and loc.tracker.held.inside_gate
    r = loc.process(2 * sec, IMG, look(0.6, True), K, Prior(pose(0.65), 11.0))
    assert not r.accepted and "while a pose inside it held 1.00 s before awaits its repeat" in r.reason
    assert loc.tracker.held is not None and loc.tracker.held.t_ns == 1 * sec
    r = loc.process(3 * sec, IMG, look(0.9, False), K, Prior(pose(0.95), 12.0))
    assert r.accepted and "repeats the pose held 2.00 s" in r.stop_reason
    assert g.relative_pose_error(r.T_map_camera, pose(0.9))[0] < 0.01
    late = VisualLocalizer(m, PARAMS, s.extract, s.describe, s.match)
    assert not late.process(1 * sec, IMG, look(0.3, False), K, Prior(pose(0.35), 10.0)).accepted
    assert not late.process(7 * sec, IMG, look(0.6, True), K, Prior(pose(0.65), 16.0)).accepted
    assert late.tracker.held is not None and late.tracker.held.t_ns == 7 * sec and not late.tracker.held.inside_gate


def test_ll_pose_with_a_stale_fused_prior_is_held_until_repeated() -> None:
    """In TRACKING, an LL pose whose fused prior is too old to confirm it (10 s past its fix)
    waits for the next frame's pose to repeat it; with a fresh prior it is accepted at once."""
    m = make_map([0.0, 1.0, 2.0, 3.0])
    s = Scene(m)
    loc = VisualLocalizer(m, PARAMS, s.extract, s.describe, s.match)
    sec = 1_000_000_000
    assert loc.process(0, IMG, s.look(pose(1.0), 1), K).accepted and loc.tracker.state == TrackingState.TRACKING
    r = loc.process(1 * sec, IMG, s.look(pose(1.2), 1), K, Prior(pose(1.3), 10.0))
    assert r.mode == "local" and not r.accepted
    assert "LL pose held until a later frame repeats it (the prior is 10.0 s past" in r.reason
    r = loc.process(2 * sec, IMG, s.look(pose(1.5), 1), K, Prior(pose(1.6), 11.0))
    assert r.mode == "local" and r.accepted and "repeats the pose held 1.00 s" in r.stop_reason
    assert loc.process(3 * sec, IMG, s.look(pose(1.8), 2), K, Prior(pose(1.8), 0.2)).accepted

    # the prior's drift grows with the odometry's path, not the time: a robot that has hardly moved since
    # its fix 10 s ago (5 cm, a slow GL on a loaded computer) keeps a fresh prior; 4 m driven does not
    rest = VisualLocalizer(m, PARAMS, s.extract, s.describe, s.match)
    assert rest.process(0, IMG, s.look(pose(1.0), 1), K).accepted
    r = rest.process(1 * sec, IMG, s.look(pose(1.2), 1), K, Prior(pose(1.3), 10.0, travel_m=0.05))
    assert r.accepted
    moved = VisualLocalizer(m, PARAMS, s.extract, s.describe, s.match)
    assert moved.process(0, IMG, s.look(pose(1.0), 1), K).accepted
    r = moved.process(1 * sec, IMG, s.look(pose(1.2), 1), K, Prior(pose(1.3), 10.0, travel_m=4.0))
    assert not r.accepted and "10.0 s past its last fix and 4.0 m of odometry, too old" in r.reason


def matching_25_with_depth(s: Scene, depth: NDArray[np.float32]) -> Callable[[Feats, NodeFeatures], tuple[
        NDArray[np.int64], NDArray[np.int64]]]:
    """The scene's matcher keeping its first 25 matches whose live keypoint has depth."""
    def few(a: Feats, b: NodeFeatures) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        i, j = s.match(a, b)
        z = depth_at(depth, np.asarray(a.keypoints, np.float64)[i], PARAMS.depth)
        keep = np.nonzero(np.isfinite(z))[0][:25]
        return i[keep], j[keep]
    return few


def test_a_weak_candidate_counts_only_when_its_keyframes_together_reach_the_inlier_floor() -> None:
    """The matcher finds 25 matches per keyframe (a wide view angle), under PnP's floor of 30.
    With `passes.pooled_min_inliers` 20, a second pass lets the candidate reach the joint refinement,
    whose keyframes together explain far more: GL and LL accept the true pose. Alone (a
    one-keyframe map) it is refused, even beside an agreeing fresh prior, and never becomes a
    provisional vote."""
    m = make_map([0.0, 1.0, 2.0, 3.0])
    s = Scene(m)
    T_true = pose(1.3, 5.0)
    depth = s.look(T_true, vpr_best=1)
    few = matching_25_with_depth(s, depth)
    off = VisualLocalizer(m, replace(PARAMS, passes=replace(PARAMS.passes, pooled_min_inliers=0)), s.extract,
                          s.describe, few)
    assert not off.localize_global(0, IMG, depth, K).accepted
    assert not off.localize_local(0, IMG, depth, K, Prior(pose(1.4, 5.0), fused=False)).accepted
    pooled = PARAMS  # pooled_min_inliers 20 by default
    assert pooled.passes.pooled_min_inliers == 20
    on = VisualLocalizer(m, pooled, s.extract, s.describe, few)
    near = Prior(pose(1.4, 5.0), fused=False)
    for r in (on.localize_global(0, IMG, depth, K), on.localize_local(0, IMG, depth, K, near)):
        assert r.accepted and len(r.keyframes) >= 2, r.reason
        assert 20 <= r.attempts[-1].inliers < 30  # its own PnP: under the floor
        assert "verified again with weak candidates pooled" in r.stop_reason
        dt, dr = g.relative_pose_error(r.T_map_camera, T_true)
        assert dt < 0.01 and dr < 0.5
    # a frame the strong candidates localize is localized by them alone: the same pose either way
    full = [VisualLocalizer(m, p, s.extract, s.describe, s.match).localize_global(0, IMG, depth, K)
            for p in (replace(PARAMS, passes=replace(PARAMS.passes, pooled_min_inliers=0)), pooled)]
    assert all(r.accepted for r in full) and np.array_equal(full[0].T_map_camera, full[1].T_map_camera)
    assert "pooled" not in full[1].stop_reason
    m1 = make_map([0.0])
    s1 = Scene(m1)
    depth1 = s1.look(pose(0.3, 5.0), vpr_best=0)
    alone = VisualLocalizer(m1, pooled, s1.extract, s1.describe, matching_25_with_depth(s1, depth1))
    for r in (alone.localize_global(0, IMG, depth1, K, Prior(pose(0.4, 3.0), 0.1)),
              alone.localize_local(0, IMG, depth1, K, Prior(pose(0.4, 3.0), 0.1, fused=True))):
        assert not r.accepted and r.provisional is None
        assert re.match(r"too few inliers \(2\d < 30; pooled", r.attempts[-1].reason), r.attempts
        # first pass: 25 matches, under PnP's floor (PnP not run); pooled: its PnP under the floor
        assert (r.attempts[0].refusal, r.attempts[0].matches) == (Refusal.MATCHES, 25)
        assert r.attempts[-1].refusal is Refusal.INLIERS and 20 <= r.attempts[-1].inliers < 30
    with pytest.raises(ValueError, match="pooled_min_inliers"):
        LocalizationParams(passes=PassesParams(pooled_min_inliers=2))


def test_a_weak_candidate_is_known_by_its_refusal_kind_not_by_the_wording_of_its_reason() -> None:
    """The pooled pass runs for candidates refused for too few inliers (or too few matches, PnP
    not run) with `floor` of them; the reason's words do not decide it."""
    assert weak(CandidateAttempt(3, 0.5, 30, 25, "refused", Refusal.INLIERS), 20)
    assert not weak(CandidateAttempt(3, 0.5, 30, 25, "refused", Refusal.INLIERS), 26)
    assert weak(CandidateAttempt(3, 0.5, 25, 0, "refused", Refusal.MATCHES), 20)
    assert not weak(CandidateAttempt(3, 0.5, 30, 25, "too few inliers (25 < 40)", Refusal.LATER), 20)
    assert not weak(CandidateAttempt(3, 0.5, 25, 0, "too few matches (25)", Refusal.DEPTH), 20)


def test_queries_run_their_geometry_on_one_blas_thread() -> None:
    """Every entry point runs under one BLAS thread (small products are slower threaded on a
    shared machine, see `OneBlasThread`); the process's own limit is back afterwards."""
    from threadpoolctl import ThreadpoolController, threadpool_limits

    m = make_map([0.0, 1.0, 2.0, 3.0])
    s = Scene(m)
    seen: list[int] = []

    def describe(img: NDArray[np.uint8]) -> NDArray[np.float32]:
        seen.append(max(lib.num_threads for lib in ThreadpoolController().select(user_api="blas").lib_controllers))
        return s.describe(img)

    loc = VisualLocalizer(m, PARAMS, s.extract, describe, s.match)
    T_true = pose(1.3, 5.0)
    with threadpool_limits(limits=2, user_api="blas"):
        depth = s.look(T_true, vpr_best=1)
        assert loc.process(0, IMG, depth, K).accepted
        assert loc.localize_global(1, IMG, depth, K).accepted
        assert loc.localize_local(2, IMG, depth, K, Prior(T_true, 0.0, fused=False)).accepted
        after = [lib.num_threads for lib in ThreadpoolController().select(user_api="blas").lib_controllers]
    assert seen == [1, 1, 1]
    assert after and set(after) == {2}
