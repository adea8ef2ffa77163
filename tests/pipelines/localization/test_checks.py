"""Each candidate check on its own: PnP, support, prior gate, joint refinement, pooled count, and
the verifier that runs them in order (synthetic scene of test_vloc)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from litevloc.pipelines.localization.checks.joint import JointCheck
from litevloc.pipelines.localization.checks.pnp import PnpCheck
from litevloc.pipelines.localization.checks.pooled import PooledCheck
from litevloc.pipelines.localization.checks.prior_gate import PriorGateCheck
from litevloc.pipelines.localization.checks.support import (
    PooledSupportCheck,
    SupportCheck,
    layer_share,
    off_layers,
    off_plane,
)
from litevloc.pipelines.localization.distinct import VerifiedPose
from litevloc.pipelines.localization.query import Query, StageTimer
from litevloc.pipelines.localization.results import CandidateAttempt
from litevloc.pipelines.localization.verifier import Candidate, CandidateVerifier
from litevloc.pipelines.pnp import Refusal
from tests.pipelines.localization.test_vloc import IMG, PARAMS, POINTS, K, Scene, make_map, pose


def _setup(T_true: np.ndarray, vpr_best: int, broken: set[int] | None = None
           ) -> tuple[CandidateVerifier, Query, Scene]:
    m = make_map([0.0, 1.0, 2.0, 3.0])
    s = Scene(m)
    depth = s.look(T_true, vpr_best=vpr_best)
    s.broken_nodes = broken or set()
    v = CandidateVerifier(m, s.extract, s.describe, s.match)
    q, _ = v.query(IMG, depth, K, PARAMS, StageTimer())
    return v, q, s


def test_pnp_fills_in_the_candidate_or_refuses_it_and_keeps_the_evidence() -> None:
    T_true = pose(1.2)
    v, q, _ = _setup(T_true, 1, broken={2})
    evidence: list[VerifiedPose] = []
    check = PnpCheck(v, PARAMS, evidence=evidence)
    c = Candidate(1, 0.9)
    assert check(c, q) is None and c.res is not None and c.attempt is not None
    assert c.T_map_camera is not None and np.linalg.norm(c.T_map_camera[:3, 3] - T_true[:3, 3]) < 0.01
    assert [e.node for e in evidence] == [1]
    bad = Candidate(2, 0.5)
    refusal = check(bad, q)
    assert refusal is not None and refusal.node == 2 and refusal.refusal is not Refusal.NONE and bad.res is None


def test_the_verifier_runs_the_checks_in_order_and_stops_at_the_first_refusal() -> None:
    v, q, _ = _setup(pose(1.2), 1)
    seen: list[str] = []

    def passes(c: Candidate, q: Query) -> CandidateAttempt | None:
        seen.append("passes")
        return None

    def refuses(c: Candidate, q: Query) -> CandidateAttempt | None:
        seen.append("refuses")
        return CandidateAttempt(c.node, c.similarity, 0, 0, "no")

    def never(c: Candidate, q: Query) -> CandidateAttempt | None:
        raise AssertionError("ran after a refusal")

    c, refusal = v.run(1, 0.9, q, [PnpCheck(v, PARAMS), passes, refuses, never])
    assert seen == ["passes", "refuses"] and refusal is not None and refusal.reason == "no" and c.res is not None
    assert v.run(1, 0.9, q, [PnpCheck(v, PARAMS), passes])[1] is None


def test_the_prior_gate_refuses_a_pose_far_from_the_prior() -> None:
    v, q, _ = _setup(pose(1.2), 1)
    c = Candidate(1, 0.9)
    assert PnpCheck(v, PARAMS)(c, q) is None
    assert PriorGateCheck(pose(1.3), 0.75, None)(c, q) is None
    far = PriorGateCheck(pose(3.0), 0.75, None)(c, q)
    assert far is not None and far.reason.startswith("inconsistent with the prior (1.8") and "> 0.75 m" in far.reason


def test_support_refuses_a_pose_whose_inliers_lie_on_one_plane_only() -> None:
    v, q, _ = _setup(pose(1.2), 1)
    c = Candidate(1, 0.9)
    assert PnpCheck(v, PARAMS)(c, q) is None
    assert SupportCheck(v)(c, q) is None  # the scene's points span 3 m in height
    tall = replace(q.params, support=replace(q.params.support, min_height_m=100.0))
    refusal = SupportCheck(v)(c, q.under(tall))
    assert refusal is not None and "one horizontal plane" in refusal.reason and refusal.refusal is Refusal.LATER


def test_support_refuses_a_pose_whose_inliers_lie_on_floor_and_ceiling_only() -> None:
    v, q, _ = _setup(pose(1.2), 1)
    c = Candidate(1, 0.9)
    assert PnpCheck(v, PARAMS)(c, q) is None
    assert c.res is not None
    some = replace(q.params, support=replace(q.params.support, min_off_layer_inliers=c.res.n_inliers // 2))
    assert SupportCheck(v)(c, q.under(some)) is None  # the scene's points spread over 3 m of height
    every = replace(q.params, support=replace(q.params.support, min_off_layer_inliers=c.res.n_inliers + 1))
    refusal = SupportCheck(v)(c, q.under(every))
    assert refusal is not None and "floor and ceiling only" in refusal.reason and refusal.refusal is Refusal.LATER


def test_support_refuses_a_pose_whose_inliers_lie_on_one_plane_of_any_orientation() -> None:
    v, q, _ = _setup(pose(1.2), 1)
    c = Candidate(1, 0.9)
    assert PnpCheck(v, PARAMS)(c, q) is None
    assert c.res is not None
    assert SupportCheck(v)(c, q) is None  # off by default
    some = replace(q.params, support=replace(q.params.support, min_off_plane_inliers=3))
    assert SupportCheck(v)(c, q.under(some)) is None  # the scene's points are spread in depth
    every = replace(q.params, support=replace(q.params.support, min_off_plane_inliers=c.res.n_inliers + 1))
    refusal = SupportCheck(v)(c, q.under(every))
    assert refusal is not None and "one plane only" in refusal.reason and refusal.refusal is Refusal.LATER


def test_off_plane_counts_the_points_off_the_plane_holding_most() -> None:
    rng = np.random.default_rng(1)
    n = np.array([0.6, 0.8, 0.0])  # a vertical wall, neither along x nor y
    in_wall = np.cross(n, [0.0, 0.0, 1.0])
    wall = 2.0 * n + rng.uniform(-2, 2, (80, 1)) * in_wall + rng.uniform(0, 2.5, (80, 1)) * np.array([0, 0, 1.0])
    wall += rng.normal(0, 0.01, wall.shape) * n  # depth noise across the wall
    desk = rng.uniform([0, 0, 0.7], [1, 1, 0.8], (12, 3))
    assert off_plane(wall) == 0
    assert off_plane(np.concatenate([wall, desk])) == 12
    assert off_plane(np.concatenate([wall, desk])) == off_plane(np.concatenate([wall, desk]))  # seeded
    assert off_plane(np.array([[0.0, 0, 0], [1, 1, 1]])) == 2 and off_plane(np.zeros((0, 3))) == 0
    assert off_plane(np.concatenate([wall, np.full((3, 3), np.nan)])) == 0  # no depth: not counted


def test_layer_share_counts_the_two_densest_horizontal_layers() -> None:
    rng = np.random.default_rng(0)
    floor, ceiling = rng.normal(0.0, 0.015, 60), rng.normal(2.6, 0.015, 30)
    wall = rng.uniform(0.3, 2.3, 30)
    assert layer_share(np.concatenate([floor, ceiling])) == 1.0
    assert abs(layer_share(np.concatenate([floor, ceiling, wall])) - 90 / 120) < 0.02
    assert layer_share(np.concatenate([floor, ceiling, wall]), layers=1) < 0.55  # the floor alone
    assert layer_share(rng.uniform(0.3, 2.3, 300)) < 0.2  # a wall's points spread over its height
    assert layer_share(np.array([np.nan, 0.0, 0.01])) == 1.0 and layer_share(np.array([])) == 0.0
    assert off_layers(np.concatenate([floor, ceiling, wall])) == 30 and off_layers(np.array([])) == 0


def test_joint_refinement_and_the_pooled_count() -> None:
    v, q, _ = _setup(pose(1.2), 1)
    c = Candidate(1, 0.9)
    assert PnpCheck(v, PARAMS)(c, q) is None
    assert c.res is not None
    strong = JointCheck(v, [0, 1, 2, 3], lambda c, weak: 2, PARAMS.pnp.min_inliers, refuse=True)
    assert strong(c, q) is None and c.joint is not None and c.joint.accepted and c.joint.consistent_keyframes >= 2
    strict = replace(q.params, refine=replace(q.params.refine, min_keyframe_inliers=100_000))
    refusal = strong(c, q.under(strict))  # no keyframe explains that many matches
    assert c.joint is not None and not c.joint.accepted
    assert refusal is not None and refusal.reason.startswith("joint refinement rejected")
    assert PooledCheck(c.res.n_inliers, 2)(c, q) is None  # at the floor: nothing to pool
    short = PooledCheck(c.res.n_inliers + 1, 2)(c, q)  # under it, its joint's keyframes (only 1) are too few
    assert short is not None and short.refusal is Refusal.INLIERS and short.reason.startswith("too few inliers")


def test_a_weak_candidate_accepted_pooled_counts_only_keyframes_that_pass_the_support_rule() -> None:
    v, q, _ = _setup(pose(1.2), 1)
    c = Candidate(1, 0.9)
    assert PnpCheck(v, PARAMS)(c, q) is None and c.res is not None
    assert JointCheck(v, [0, 1, 2, 3], lambda c, weak: 2, PARAMS.pnp.min_inliers, refuse=True)(c, q) is None
    assert c.joint is not None and c.joint.consistent_keyframes >= 3
    pts = c.joint.inlier_points_map()
    assert {k: len(p) for k, p in pts.items()} == c.joint.inliers_per_keyframe
    near = np.min(np.linalg.norm(np.concatenate(list(pts.values()))[:, None] - POINTS[None], axis=2), axis=1)
    assert np.median(near) < 0.02 and near.max() < 0.2  # the scene's points (live depth read at whole pixels)
    off = sorted((off_layers(p @ np.array([0.0, -1.0, 0.0])), k) for k, p in pts.items())
    weak = c.res.n_inliers + 1  # a floor above the candidate's own inliers: it passed pooled

    def rule(n: int) -> Query:
        return q.under(replace(q.params, support=replace(q.params.support, min_off_layer_inliers=n)))

    n_kf = len(off)
    assert PooledSupportCheck(v, weak, n_kf)(c, rule(off[0][0])) is None  # every keyframe passes on its own
    assert off[0][0] < off[1][0]
    dropped = PooledSupportCheck(v, weak, n_kf)(c, rule(off[0][0] + 1))  # the weakest keyframe drops out
    assert dropped is not None and dropped.refusal is Refusal.LATER
    assert dropped.reason.startswith(f"pooled support too weak ({c.joint.n_inliers - len(pts[off[0][1]])} inliers "
                                     f"over {n_kf - 1} keyframe(s)")
    assert f"keyframe {off[0][1]}: support on floor and ceiling only" in dropped.reason
    assert PooledSupportCheck(v, weak, n_kf - 1)(c, rule(off[0][0] + 1)) is None  # the others still suffice
    assert PooledSupportCheck(v, c.res.n_inliers, n_kf)(c, rule(10_000)) is None  # strong: its own inliers decide
