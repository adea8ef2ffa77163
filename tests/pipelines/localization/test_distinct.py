"""GL's distinctiveness test (issue #43): a pose that another place verifies nearly as well
(a repeating corridor) is refused without a trusted prior."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numpy as np
import pytest
from numpy.typing import NDArray

from litevloc.base import geometry as g
from litevloc.base.params.localization import DistinctivenessParams, LocalizationParams
from litevloc.pipelines.localization.distinct import Rival, VerifiedPose, ambiguity, rivals_to_verify, strongest_rival
from litevloc.pipelines.localization.prior import Prior
from litevloc.pipelines.localization.vloc import VisualLocalizer
from litevloc.pipelines.topomap.types import NodeFeatures, TopoMap
from tests.pipelines.localization.test_vloc import IMG, PARAMS, Feats, K, Scene, make_map, pose

# re-ranking and guided matching off: over these large synthetic keypoint sets they dominate the time
GUARD = replace(PARAMS, refine=replace(PARAMS.refine, extra_matching="model"),
                global_search=replace(PARAMS.global_search, top_k=4,
                                      rerank=False), distinctiveness=replace(PARAMS.distinctiveness, ratio=2.0))


def _corridor() -> TopoMap:
    """Keyframes at x = 0, 1 and at x = 10, 11 whose features are copies of the first two's:
    the same texture one period (10 m) along the corridor."""
    m = make_map([0.0, 1.0, 10.0, 11.0])
    feats = list(m.features)
    for k in (2, 3):
        f = feats[k - 2]
        feats[k] = NodeFeatures(f.keypoints.copy(), f.descriptors.copy(), f.scores.copy(), f.image_size)
    return replace(m, features=feats)


def test_rivals_are_candidates_at_another_pose_and_the_ratio_decides() -> None:
    win = pose(0.0)
    verified = [VerifiedPose(1, pose(0.05), 90), VerifiedPose(2, pose(10.0), 40), VerifiedPose(3, pose(0.0, 30.0), 20)]
    rival = strongest_rival(win, verified, 0.3, 10.0)
    assert rival is not None and rival.node == 2 and rival.apart_m == pytest.approx(10.0)
    assert strongest_rival(win, verified[:1], 0.3, 10.0) is None  # 5 cm away: the same place
    turned = strongest_rival(win, verified[2:], 0.3, 10.0)
    assert turned is not None and turned.apart_deg == pytest.approx(30.0)
    assert ambiguity(0, 100, Rival(2, 50, 10.0, 0.0), 2.0).startswith("ambiguous: node 0 (100 inliers) and node 2")
    assert ambiguity(0, 101, Rival(2, 50, 10.0, 0.0), 2.0) == ""
    assert ambiguity(0, 100, Rival(2, 99, 10.0, 0.0), 0.0) == ""  # off
    assert ambiguity(0, 100, None, 2.0) == ""
    with pytest.raises(ValueError, match=r"ratio must be a finite number in 0 or \[1, inf\), got 0\.5"):
        LocalizationParams(distinctiveness=DistinctivenessParams(ratio=0.5))


def test_gl_refuses_a_pose_that_another_place_verifies_as_well() -> None:
    m = _corridor()
    s = Scene(m)
    T_true = pose(0.3, 4.0)
    depth = s.look(T_true, vpr_best=0)
    s.vpr[2] = 0.9  # the aliased place ranks second
    off = VisualLocalizer(m, replace(GUARD, distinctiveness=replace(GUARD.distinctiveness, ratio=0.0)), s.extract,
                          s.describe, s.match)
    assert off.localize_global(0, IMG, depth, K).accepted  # without the test: a fix at one of the two
    on = VisualLocalizer(m, GUARD, s.extract, s.describe, s.match)
    r = on.localize_global(0, IMG, depth, K)
    assert not r.accepted and r.T_map_camera is None and r.provisional is None
    assert "ambiguous" in r.reason and "10.00 m" in r.reason, r.reason
    # a fresh prior is trusted: the pose that agrees with it is accepted
    r = on.localize_global(0, IMG, depth, K, Prior(pose(0.4, 3.0), 0.1))
    assert r.accepted, r.reason
    assert g.relative_pose_error(r.T_map_camera, T_true)[0] < 0.01
    # the rivals verified after the winner are bounded
    none = VisualLocalizer(m, replace(GUARD, distinctiveness=replace(GUARD.distinctiveness, max_rivals=0)), s.extract,
                           s.describe, s.match)
    assert none.localize_global(0, IMG, depth, K).accepted
    # where the other period does not verify (its matches garbage), the place is distinctive
    s.broken_nodes = {2, 3}
    r = on.localize_global(0, IMG, depth, K)
    assert r.accepted and g.relative_pose_error(r.T_map_camera, T_true)[0] < 0.01, r.reason


def test_rivals_to_verify_skip_weak_candidates() -> None:
    counts = {0: 100, 1: 80, 2: 40, 3: 60, 4: 55}
    assert rivals_to_verify([1, 2, 3, 4, 5], counts, 0, 2.0, 2) == [1, 3]  # 2: < 100 / 2
    assert rivals_to_verify([1, 2, 3, 4, 5], counts, 0, 2.0, 9) == [1, 3, 4, 5]  # 5: not re-ranked, passes


Pairs = tuple[NDArray[np.int64], NDArray[np.int64]]


def _counting(s: Scene, seen: list[int]) -> Callable[[Feats, NodeFeatures], Pairs]:
    """The scene's matcher, recording the node of every call in `seen`."""
    def match(a: Feats, b: NodeFeatures) -> Pairs:
        seen.append(next(i for i, f in enumerate(s.map.features) if f is b))
        return s.match(a, b)
    return match


def test_the_test_stops_once_a_rival_decides() -> None:
    m = _corridor()
    s = Scene(m)
    depth = s.look(pose(0.3, 4.0), vpr_best=0)
    s.vpr[1:] = [0.9, 0.8, 0.7]  # GL order 0, 1, 2 (the alias of 0), 3 (the alias of 1)
    seen: list[int] = []
    loc = VisualLocalizer(m, GUARD, s.extract, s.describe, _counting(s, seen))
    r = loc.localize_global(0, IMG, depth, K)
    assert not r.accepted and "node 2" in r.reason and 3 not in seen, (r.reason, seen)  # node 3: never matched


def test_the_screen_verifies_only_candidates_the_reranking_puts_elsewhere() -> None:
    # guided joint: no matcher
    screen = replace(GUARD, refine=PARAMS.refine, global_search=replace(GUARD.global_search, rerank=True),
                     distinctiveness=replace(GUARD.distinctiveness, screen=True))
    m = make_map([0.0, 1.0, 2.0])
    s = Scene(m)
    depth = s.look(pose(0.8, 3.0), vpr_best=1)
    runs: dict[bool, list[int]] = {}
    for on in (False, True):
        runs[on] = []
        loc = VisualLocalizer(m, replace(screen, distinctiveness=replace(screen.distinctiveness, screen=on)),
                              s.extract, s.describe, _counting(s, runs[on]))
        r = loc.localize_global(0, IMG, depth, K)
        assert r.accepted and g.relative_pose_error(r.T_map_camera, pose(0.8, 3.0))[0] < 0.01, r.reason
    assert len(runs[False]) == 3 and len(runs[True]) == 1, runs  # the same place: no matcher run for the test
    # the aliased copy of the corridor: its re-ranking pose is 10 m away, so it is verified and decides
    m = _corridor()
    s = Scene(m)
    depth = s.look(pose(0.3, 4.0), vpr_best=0)
    r = VisualLocalizer(m, screen, s.extract, s.describe, s.match).localize_global(0, IMG, depth, K)
    assert not r.accepted and "ambiguous" in r.reason and "10.00 m" in r.reason, r.reason


def _copy_of_one_place() -> TopoMap:
    """Keyframes at x = 0 and x = 10, the second's features a copy of the first's: one place
    seen by one keyframe, and its copy 10 m along; no neighbour confirms either."""
    m = make_map([0.0, 10.0])
    f = m.features[0]
    return replace(m, features=[f, NodeFeatures(f.keypoints.copy(), f.descriptors.copy(), f.scores.copy(),
                                                f.image_size)])


def test_one_keyframe_pose_is_accepted_where_no_other_place_verifies_near_it() -> None:
    # one keyframe sees the place: no second keyframe, and no rival; without a trusted prior
    m = make_map([0.0])
    s = Scene(m)
    T_true = pose(0.3, 5.0)
    depth = s.look(T_true, vpr_best=0)
    p = replace(GUARD, distinctiveness=replace(GUARD.distinctiveness, ratio=0.0))
    r = VisualLocalizer(m, p, s.extract, s.describe, s.match).localize_global(0, IMG, depth, K)
    assert r.accepted and "one keyframe, no rival within x2" in r.stop_reason, r.stop_reason
    assert g.relative_pose_error(r.T_map_camera, T_true)[0] < 0.01
    off = replace(p, confirm=replace(p.confirm, gl_single_distinct_ratio=0.0))
    r = VisualLocalizer(m, off, s.extract, s.describe, s.match).localize_global(0, IMG, depth, K)
    assert not r.accepted and r.provisional is not None  # the second keyframe is required again
    # a copy of the place 10 m along verifies as well: neither is accepted on one keyframe
    m = _copy_of_one_place()
    s = Scene(m)
    depth = s.look(T_true, vpr_best=0)
    r = VisualLocalizer(m, p, s.extract, s.describe, s.match).localize_global(0, IMG, depth, K)
    assert not r.accepted and r.provisional is not None, r.stop_reason


def test_a_rival_resting_on_floor_tiles_alone_is_no_evidence_of_another_place(
        monkeypatch: pytest.MonkeyPatch) -> None:
    import litevloc.pipelines.localization.checks.distinctiveness as dist

    m = _corridor()
    s = Scene(m)
    depth = s.look(pose(0.3, 4.0), vpr_best=0)
    s.vpr[2] = 0.9
    loc = VisualLocalizer(m, GUARD, s.extract, s.describe, s.match)
    assert not loc.localize_global(0, IMG, depth, K).accepted  # the copy 10 m along decides
    real = dist.flat_at
    monkeypatch.setattr(dist, "flat_at", lambda v, node, T, q: node in (2, 3) or real(v, node, T, q))
    r = loc.localize_global(0, IMG, depth, K)
    assert r.accepted and g.relative_pose_error(r.T_map_camera, pose(0.3, 4.0))[0] < 0.01, r.reason


def test_a_pose_is_refused_where_a_place_verified_before_it_had_more_inliers() -> None:
    # the true place (x = 0, 1) and its copy (x = 10, 11); the true place's neighbour does not
    # match (a changed scene), so only the copy passes the joint check, after the true place
    m = _corridor()
    s = Scene(m)
    s.broken_nodes = {1}
    depth = s.look(pose(0.3, 4.0), vpr_best=0)
    s.vpr[2] = 0.9
    off = replace(GUARD, distinctiveness=replace(GUARD.distinctiveness, ratio=0.0, stronger_rival=False),
                  confirm=replace(GUARD.confirm, gl_single_distinct_ratio=0.0))
    r = VisualLocalizer(m, off, s.extract, s.describe, s.match).localize_global(0, IMG, depth, K)
    assert r.accepted and r.ref_node == 2, r.stop_reason  # the wrong pose, 10 m along
    on = replace(off, distinctiveness=replace(off.distinctiveness, stronger_rival=True))
    r = VisualLocalizer(m, on, s.extract, s.describe, s.match).localize_global(0, IMG, depth, K)
    assert not r.accepted and "ambiguous: node 2" in r.reason, r.reason
