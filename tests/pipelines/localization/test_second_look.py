"""GL's full-resolution second look (`pipelines.localization.second_look`, `passes.second_look_nodes`):
which refused candidates it looks at again, the keyframe features it extracts from the stored
images, and a GL query the first look refuses that the second accepts, on the synthetic scene of
test_vloc (exact truth)."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import cv2
import numpy as np
import pytest
from numpy.typing import NDArray

from litevloc.base import geometry as g
from litevloc.pipelines.localization.checks.look_precheck import precheck_inliers
from litevloc.pipelines.localization.checks.see_through import moved_onto_live_depth, see_through
from litevloc.pipelines.localization.passes import second_look_nodes
from litevloc.pipelines.localization.prior import Prior
from litevloc.pipelines.localization.results import CandidateAttempt, LocalizationResult
from litevloc.pipelines.localization.second_look import SecondLook, StoredImageFeatures
from litevloc.pipelines.localization.tracking import TrackingState
from litevloc.pipelines.localization.vloc import VisualLocalizer
from litevloc.pipelines.pnp import Refusal
from litevloc.pipelines.topomap.types import NodeFeatures, TopoMap
from tests.pipelines.localization.test_depth_align import K as CORNER_K
from tests.pipelines.localization.test_depth_align import corner_depth, corner_points
from tests.pipelines.localization.test_vloc import (
    IMG,
    PARAMS,
    POINTS,
    Feats,
    K,
    Scene,
    make_map,
    match_by_id,
    matching_25_with_depth,
    pose,
)

SMALLER = (120, 160)  # the first look's extractor input (h, w): IMG (240x320) is larger


def _jpeg(level: int) -> bytes:
    ok, buf = cv2.imencode(".jpg", np.full((24, 32, 3), level, np.uint8))
    assert ok
    return buf.tobytes()


def _level(node: int) -> int:
    return 40 + 40 * node  # a keyframe's stored image: one grey level per node (IMG, the query, is 0)


def _with_images(m: TopoMap) -> TopoMap:
    """`m` with a stored image per keyframe and its keypoints' map depth (the see-through check)."""
    feats = []
    for k, f in enumerate(m.features):
        ids = np.asarray(f.descriptors[:, 0], np.int64)
        z = g.transform_points(g.invert(m.T_map_camera[k]), POINTS[ids])[:, 2]
        feats.append(replace(f, depth=z.astype(np.float32)))
    return replace(m, features=feats, images_jpeg=[_jpeg(_level(i)) for i in range(m.n_nodes)])


class FullResolution:
    """The 'higher resolution' extractor: the query's or a keyframe's full feature set, told apart
    by the image's grey level; counts its calls per node."""

    def __init__(self, s: Scene, m: TopoMap) -> None:
        self.s, self.feats = s, list(m.features)
        self.calls: list[int] = []

    def extract(self, img: NDArray[np.uint8]) -> Feats | NodeFeatures:
        level = float(img.mean())
        if level < 20:
            assert self.s.current is not None
            return self.s.current
        node = round((level - 40) / 40)
        self.calls.append(node)
        return self.feats[node]


def test_second_look_nodes_are_the_refused_candidates_with_most_inliers_above_the_gate() -> None:
    att = (CandidateAttempt(3, 0.9, 60, 12, "too few inliers", Refusal.INLIERS),
           CandidateAttempt(5, 0.8, 90, 25, "too few inliers", Refusal.INLIERS),
           CandidateAttempt(7, 0.7, 30, 0, "too few matches", Refusal.MATCHES),
           CandidateAttempt(3, 0.9, 60, 31, "pooled: too few", Refusal.INLIERS),  # a later pass, more inliers
           CandidateAttempt(9, 0.6, 80, 25, "too few inliers", Refusal.INLIERS))
    assert second_look_nodes(att, 2, 10) == [3, 5]  # 31 inliers; then of two with 25, the one with more matches
    assert second_look_nodes(att, 5, 10) == [3, 5, 9]
    assert second_look_nodes(att, 5, 0) == [3, 5, 9, 7]
    assert second_look_nodes(att, 5, 40) == []


def test_stored_image_features_are_extracted_once_and_the_cache_is_bounded() -> None:
    seen: list[float] = []

    def extract(img: NDArray[np.uint8]) -> str:  # type: ignore[return-value]
        assert img.shape == (24, 32, 3) and img.dtype == np.uint8
        seen.append(float(img.mean()))
        return f"node at {round(float(img.mean()))}"

    f = StoredImageFeatures([_jpeg(_level(i)) for i in range(3)], extract, capacity=2)  # type: ignore[arg-type]
    assert len(f) == 3 and f[1] == f[1] == "node at 80" and f.extracted == 1
    f[0], f[2]
    f[1]
    assert f.extracted == 4 and [round(v) for v in seen] == [80, 40, 120, 80]
    with pytest.raises(IndexError):
        f[3]
    bad = StoredImageFeatures([b"not a jpeg"], extract)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="keyframe 0's stored image does not decode"):
        bad[0]


def test_a_gl_query_the_first_look_refuses_is_accepted_by_the_second() -> None:
    """The first look's matcher finds 25 matches with depth per keyframe (a wide view change), under
    PnP's floor of 30 with pooling off: refused. The second look's features match fully: GL
    accepts the true pose, says so, keeps both looks' attempts and times the second."""
    m = _with_images(make_map([0.0, 1.0, 2.0, 3.0]))
    s = Scene(m)
    T_true = pose(1.3, 5.0)
    depth = s.look(T_true, vpr_best=1)
    few = matching_25_with_depth(s, depth)
    p = replace(PARAMS, passes=replace(PARAMS.passes, pooled_min_inliers=0),
                second_look=replace(PARAMS.second_look, candidates=2, from_inliers=0))
    full = FullResolution(s, m)
    look = SecondLook(m, p, full.extract, s.describe, match_by_id, SMALLER)
    loc = VisualLocalizer(m, p, s.extract, s.describe, few, second_look=look)
    off = VisualLocalizer(m, replace(p, second_look=replace(p.second_look, candidates=0)), s.extract, s.describe, few,
                          second_look=look)
    refused = off.localize_global(0, IMG, depth, K)
    assert not refused.accepted and "full resolution" not in refused.stop_reason
    r = loc.localize_global(0, IMG, depth, K)
    assert r.accepted, r.stop_reason
    assert r.stop_reason.startswith("looked at again at full resolution (nodes [")
    dt, dr = g.relative_pose_error(r.T_map_camera, T_true)
    assert dt < 0.005 and dr < 0.2
    assert len(r.attempts) > len(refused.attempts) and r.timings_ms["second_look"] > 0
    assert r.timings_ms["total"] >= r.timings_ms["second_look"]
    assert set(full.calls) <= {0, 1, 2, 3}
    # a query the first look accepts never looks again
    n_calls = len(full.calls)
    plain = VisualLocalizer(m, p, s.extract, s.describe, s.match, second_look=look).localize_global(0, IMG, depth, K)
    assert plain.accepted and "second_look" not in plain.timings_ms and len(full.calls) == n_calls
    # the same look, its pose moved 1 m ahead: the keyframes' points then lie in front of the live
    # depth (it sees through the map) and it is refused, saying so
    ahead = SecondLook(m, p, full.extract, s.describe, match_by_id, SMALLER)
    verify = ahead.global_.localize

    def moved(*args: Any, **kwargs: Any) -> LocalizationResult:
        res = verify(*args, **kwargs)
        assert res.T_map_camera is not None
        return replace(res, T_map_camera=res.T_map_camera @ g.make_T(np.eye(3), [0, 0, 1.0]))

    ahead.global_.localize = moved  # type: ignore[method-assign]
    r4 = VisualLocalizer(m, p, s.extract, s.describe, few, second_look=ahead).localize_global(0, IMG, depth, K)
    assert not r4.accepted and "sees through the map" in r4.stop_reason, r4.stop_reason
    # an image no larger than what the first look's extractor sees has nothing finer to show
    n_calls = len(full.calls)
    same = SecondLook(m, p, full.extract, s.describe, match_by_id, (240, 320))
    r3 = VisualLocalizer(m, p, s.extract, s.describe, few, second_look=same).localize_global(0, IMG, depth, K)
    assert not r3.accepted and "second_look" not in r3.timings_ms and len(full.calls) == n_calls


def test_the_second_look_refuses_what_its_features_do_not_verify_and_a_gate_skips_it() -> None:
    m = _with_images(make_map([0.0, 1.0, 2.0]))
    s = Scene(m)
    depth = s.look(pose(1.0), 1)
    s.broken_nodes = {0, 1, 2}
    p = replace(PARAMS, passes=replace(PARAMS.passes, pooled_min_inliers=0),
                second_look=replace(PARAMS.second_look, candidates=3, from_inliers=0))
    full = FullResolution(s, m)

    def garbage(a: Feats, b: NodeFeatures) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        rng = np.random.default_rng(len(b.keypoints))
        return rng.integers(0, len(a.keypoints), 200), rng.integers(0, len(b.keypoints), 200)

    loc = VisualLocalizer(m, p, s.extract, s.describe, s.match,
                          second_look=SecondLook(m, p, full.extract, s.describe, garbage, SMALLER))
    r = loc.localize_global(0, IMG, depth, K)
    assert not r.accepted and r.T_map_camera is None
    assert "looked at again at full resolution (nodes [" in r.stop_reason and "second_look" in r.timings_ms
    gated = VisualLocalizer(m, replace(p, second_look=replace(p.second_look, from_inliers=30)), s.extract, s.describe,
                            s.match,
                            second_look=SecondLook(m, p, full.extract, s.describe, garbage, SMALLER))
    r2 = gated.localize_global(0, IMG, depth, K)
    assert not r2.accepted and "second_look" not in r2.timings_ms  # no candidate reached the gate


def test_second_look_needs_its_models_and_the_maps_images() -> None:
    m = make_map([0.0, 1.0])
    s = Scene(m)
    p = replace(PARAMS, second_look=replace(PARAMS.second_look, candidates=1))
    with pytest.raises(ValueError, match=r"second_look\.candidates > 0 needs the second look's models"):
        VisualLocalizer(m, p, s.extract, s.describe, s.match)
    with pytest.raises(ValueError, match="second look needs every keyframe's stored image"):
        SecondLook(replace(m, images_jpeg=[]), p, s.extract, s.describe, s.match, SMALLER)
    with pytest.raises(ValueError, match=r"candidates must be an integer in \[0, inf\), got -1"):
        replace(PARAMS, second_look=replace(PARAMS.second_look, candidates=-1))


def test_a_pose_that_puts_the_maps_points_in_front_of_the_live_surface_sees_through_it() -> None:
    """A wall of map points 5 m ahead, the live depth 5 m everywhere: the true pose sees none of
    them in front of the surface; a pose 1 m nearer puts all of them there (a camera that would
    see the wall at 4 m sees it at 5 m); 1 m farther puts them behind it (occluded: allowed).
    Points without live depth are not counted."""
    xy = np.stack(np.meshgrid(np.linspace(-1, 1, 10), np.linspace(-0.6, 0.6, 6)), -1).reshape(-1, 2)
    wall = np.column_stack([xy, np.full(len(xy), 5.0)])
    depth = np.full((240, 320), 5.0, np.float32)
    assert see_through(wall, np.eye(4), K, depth) == (60, 0.0)
    n, share = see_through(wall, g.make_T(np.eye(3), [0, 0, 1.0]), K, depth)
    assert n > 0 and share == 1.0
    n, share = see_through(wall, g.make_T(np.eye(3), [0, 0, -1.0]), K, depth)
    assert n == 60 and share == 0.0
    depth[:, :160] = np.nan  # the left half has no live depth
    n, _ = see_through(wall, np.eye(4), K, depth)
    assert 0 < n < 60


def test_an_ll_query_the_first_look_refuses_is_accepted_by_the_second_within_the_priors_gate() -> None:
    """LL from a prior near the truth: refused on 25 matches per keyframe, accepted by the second
    look where `second_look.local` is on; from a prior 2 m away the second look's pose is outside
    the prior's gate: refused."""
    m = _with_images(make_map([0.0, 1.0, 2.0, 3.0]))
    s = Scene(m)
    T_true = pose(1.3, 5.0)
    depth = s.look(T_true, vpr_best=1)
    few = matching_25_with_depth(s, depth)
    p = replace(PARAMS, passes=replace(PARAMS.passes, pooled_min_inliers=0),
                second_look=replace(PARAMS.second_look, candidates=2, from_inliers=0, local=True))
    full = FullResolution(s, m)
    look = SecondLook(m, p, full.extract, s.describe, match_by_id, SMALLER)
    loc = VisualLocalizer(m, p, s.extract, s.describe, few, second_look=look)
    off = VisualLocalizer(m, replace(p, second_look=replace(p.second_look, candidates=0)), s.extract, s.describe, few)
    assert not off.localize_local(0, IMG, depth, K, Prior(pose(1.4, 5.0), fused=False)).accepted
    gl_only = VisualLocalizer(m, replace(p, second_look=replace(p.second_look, local=False)), s.extract, s.describe,
                              few, second_look=look)
    # LL's look is its own switch
    assert not gl_only.localize_local(0, IMG, depth, K, Prior(pose(1.4, 5.0), fused=False)).accepted
    r = loc.localize_local(0, IMG, depth, K, Prior(pose(1.4, 5.0), fused=False))
    assert r.accepted and r.mode == "local", r.stop_reason
    assert r.stop_reason.startswith("looked at again at full resolution (nodes [")
    dt, dr = g.relative_pose_error(r.T_map_camera, T_true)
    assert dt < 0.005 and dr < 0.2
    far = loc.localize_local(0, IMG, depth, K, Prior(pose(3.3, 5.0), fused=False))
    assert not far.accepted and any("inconsistent with the prior" in a.reason for a in far.attempts)


def test_after_an_ll_query_only_the_second_look_accepted_the_next_matches_those_keyframes_alone() -> None:
    """`second_look.stay`: the LL query after one the second look alone accepted runs the matcher
    model in its first look only for that query's keyframes (fewer model calls) and is again
    accepted at full resolution; off, the first look runs the model for every candidate again.
    A GL query in between ends it."""
    m = _with_images(make_map([0.0, 1.0, 2.0, 3.0]))
    s = Scene(m)
    depth = s.look(pose(1.3, 5.0), vpr_best=1)
    few = matching_25_with_depth(s, depth)
    p = replace(PARAMS, passes=replace(PARAMS.passes, pooled_min_inliers=0),
                second_look=replace(PARAMS.second_look, candidates=2, from_inliers=0, local=True, stay=True))
    prior = Prior(pose(1.4, 5.0), fused=False)

    def run(params: Any) -> tuple[VisualLocalizer, list[list[int]], list[LocalizationResult]]:
        matched: list[int] = []
        loc: VisualLocalizer | None = None

        def counting(a: Feats, b: NodeFeatures) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
            assert loc is not None
            matched.append(next(k for k, f in enumerate(loc.verifier.map.features) if f is b))
            return few(a, b)

        loc = VisualLocalizer(m, params, s.extract, s.describe, counting,
                              second_look=SecondLook(m, params, FullResolution(s, m).extract, s.describe,
                                                     match_by_id, SMALLER))
        calls, results = [], []
        for t in range(2):
            results.append(loc.localize_local(t, IMG, depth, K, prior))
            calls.append(list(matched))
            matched.clear()
        return loc, calls, results

    loc, calls, (r1, r2) = run(p)
    assert r1.accepted and r1.second_look and r2.accepted and r2.second_look, (r1.reason, r2.reason)
    assert set(calls[1]) <= set(r1.keyframes) and len(calls[1]) < len(calls[0]), (calls, r1.keyframes)
    assert loc.local_search.full_resolution == r2.keyframes
    _, calls_off, (o1, o2) = run(replace(p, second_look=replace(p.second_look, stay=False)))
    assert o1.accepted and o2.accepted and calls_off[1] == calls_off[0] == calls[0]
    loc.tracker.state = TrackingState.LOST  # LOST -> GL: what LL does after it starts afresh
    loc.process(2, IMG, depth, K, prior)
    assert loc.local_search.full_resolution == ()


def test_the_ll_look_keeps_closer_to_a_last_pose_prior_than_ll_does() -> None:
    """A prior 0.5 m from the truth lies inside LL's own gate (`prior_gate.radius_m` 0.75 m) but outside
    its look's (`second_look.prior_gate_m` 0.25 m): the look's pose is refused; with the look's
    gate as wide as LL's it is accepted."""
    m = _with_images(make_map([0.0, 1.0, 2.0, 3.0]))
    s = Scene(m)
    depth = s.look(pose(1.3, 5.0), vpr_best=1)
    few = matching_25_with_depth(s, depth)
    p = replace(PARAMS, passes=replace(PARAMS.passes, pooled_min_inliers=0),
                second_look=replace(PARAMS.second_look, candidates=2, from_inliers=0, local=True))
    assert p.prior_gate.radius_m == 0.75 and p.second_look.prior_gate_m == 0.25
    full = FullResolution(s, m)

    def local(params: Any) -> LocalizationResult:
        look = SecondLook(m, params, full.extract, s.describe, match_by_id, SMALLER)
        loc = VisualLocalizer(m, params, s.extract, s.describe, few, second_look=look)
        return loc.localize_local(0, IMG, depth, K, Prior(pose(1.8, 5.0), fused=False))

    tight = local(p)
    assert not tight.accepted and any("inconsistent with the prior" in a.reason for a in tight.attempts)
    assert local(replace(p, second_look=replace(p.second_look, prior_gate_m=0.75))).accepted


def test_a_look_pose_that_sees_through_by_a_small_miss_is_moved_onto_the_live_depth() -> None:
    """A room corner, the look's pose 17 cm and 2 deg off towards it: the map points it puts in front of
    the live depth make it see through; moved onto the live depth it is accepted, close to the
    truth, its covariance grown by the move. A miss of 0.45 m is beyond `see_through.align_m`, one
    turned 8 deg beyond `see_through.align_deg`: they stay refused; so does the small miss where
    moving is off (`see_through.align_m` 0)."""
    T_true = g.make_T(g.so3_exp(np.array([0.1, 0.35, 0.02])), np.array([0.1, 0.0, 0.2]))
    depth = corner_depth(T_true)
    points = corner_points(g.make_T(g.so3_exp(np.array([0.05, 0.52, 0.0])), np.array([-0.3, -0.1, 0.0])))
    p = replace(PARAMS, second_look=replace(PARAMS.second_look, candidates=2))
    assert p.see_through.align_m == 0.3 and p.see_through.max_share == 0.3

    def look_at(T: NDArray[np.float64]) -> LocalizationResult:
        return LocalizationResult(0, "global", True, "ok", T_map_camera=T, covariance=1e-4 * np.eye(6),
                                  keyframes=(0,), stop_reason="looked at again")

    ahead = T_true @ g.make_T(g.so3_exp(np.radians([1.0, -2.0, 0.0])), [0.08, 0.05, 0.14])
    assert see_through(points, ahead, CORNER_K, depth)[1] > 0.3
    moved = moved_onto_live_depth(look_at(ahead), points, CORNER_K, depth, p)
    assert moved is not None and moved.accepted and "onto the live depth" in moved.stop_reason
    assert moved.T_map_camera is not None and moved.covariance is not None
    dt, dr = g.relative_pose_error(moved.T_map_camera, T_true)
    assert dt < 0.01 and dr < 0.5
    assert moved.covariance[0, 0] > 0.01 and see_through(points, moved.T_map_camera, CORNER_K, depth)[1] < 0.15
    far = T_true @ g.make_T(np.eye(3), [0.0, 0.0, 0.45])
    assert moved_onto_live_depth(look_at(far), points, CORNER_K, depth, p) is None
    turned = T_true @ g.make_T(g.so3_exp(np.radians([0.0, 8.0, 0.0])), [0.02, 0.0, 0.05])  # 8 deg > 6
    assert see_through(points, turned, CORNER_K, depth)[1] > 0.3
    assert moved_onto_live_depth(look_at(turned), points, CORNER_K, depth, p) is None
    wider = replace(p, see_through=replace(p.see_through, align_deg=9.0))
    assert moved_onto_live_depth(look_at(turned), points, CORNER_K, depth, wider) is not None
    never = replace(p, see_through=replace(p.see_through, align_m=0))
    assert moved_onto_live_depth(look_at(ahead), points, CORNER_K, depth, never) is None


def test_a_gl_query_looks_again_only_where_the_look_fits_in_its_time_budget() -> None:
    """The look is part of the GL query its time budget bounds: with the median of the last looks
    (the expected cost) past the budget the query is refused, saying why, and no look runs; with
    no look measured yet, a cheaper expected look, or no budget at all, it looks and accepts."""
    m = _with_images(make_map([0.0, 1.0, 2.0, 3.0]))
    s = Scene(m)
    depth = s.look(pose(1.3, 5.0), vpr_best=1)
    few = matching_25_with_depth(s, depth)
    budget = 1e6  # ms: far more than the synthetic first look spends
    p = replace(PARAMS, passes=replace(PARAMS.passes, pooled_min_inliers=0),
                second_look=replace(PARAMS.second_look, candidates=2, from_inliers=0),
                global_search=replace(PARAMS.global_search, time_budget_ms=budget))
    full = FullResolution(s, m)

    def localizer(params: Any) -> VisualLocalizer:
        return VisualLocalizer(m, params, s.extract, s.describe, few,
                               second_look=SecondLook(m, params, full.extract, s.describe, match_by_id, SMALLER))

    loc = localizer(p)
    first = loc.localize_global(0, IMG, depth, K)  # no look measured yet: it runs, and is measured
    assert first.accepted and "second_look" in first.timings_ms
    assert list(loc.global_search.look_ms) == [first.timings_ms["second_look"]]
    loc.global_search.look_ms.extend([2 * budget] * 3)  # the median look now costs twice the budget
    n_calls = len(full.calls)
    r = loc.localize_global(0, IMG, depth, K)
    assert not r.accepted and "second_look" not in r.timings_ms and len(full.calls) == n_calls
    assert "no second look" in r.stop_reason and "time budget" in r.stop_reason, r.stop_reason
    loc.global_search.look_ms.clear()
    loc.global_search.look_ms.extend([0.5 * budget] * 3)
    assert loc.localize_global(0, IMG, depth, K).accepted  # an expected look that fits
    unbounded = localizer(replace(p, global_search=replace(p.global_search, time_budget_ms=0.0)))
    unbounded.global_search.look_ms.extend([2 * budget] * 3)
    assert unbounded.localize_global(0, IMG, depth, K).accepted  # no budget: the look always runs
    # recovering after tracking was lost: the bound is 2x the LL cost, also with one candidate only
    for only in (None, [1]):
        rec = unbounded.global_search.localize(0, IMG, depth, K, unbounded.params, recovering_ll_ms=[1.0], only=only)
        assert not rec.accepted and "no second look" in rec.stop_reason, rec.stop_reason


def test_the_pre_check_keeps_a_pair_that_shares_the_scene_and_refuses_one_that_does_not() -> None:
    """Mutual nearest neighbours of the descriptors + PnP with the live depth: the true pair
    (same points seen from 0.3 m and 5 deg apart) keeps most of its points as inliers (some lie
    outside the keyframe); against a keyframe whose descriptors are another scene's (scrambled)
    almost none survive RANSAC."""
    m = make_map([0.0, 1.0])
    s = Scene(m)
    depth = s.look(pose(0.3, 5.0), vpr_best=0)
    live = s.current
    assert live is not None
    mnn, inl = precheck_inliers(live, depth, K, m.features[0], m.K[0], PARAMS)
    assert mnn > 100 and inl > 0.6 * mnn
    f = m.features[0]
    scrambled = replace(f, descriptors=f.descriptors[np.random.default_rng(1).permutation(len(f.descriptors))])
    _, inl_bad = precheck_inliers(live, depth, K, scrambled, m.K[0], PARAMS)
    assert inl_bad < 10


def test_a_candidate_the_pre_check_refuses_is_never_matched_at_full_resolution() -> None:
    m = _with_images(make_map([0.0, 1.0, 2.0, 3.0]))
    s = Scene(m)
    T_true = pose(1.3, 5.0)
    depth = s.look(T_true, vpr_best=1)
    few = matching_25_with_depth(s, depth)
    p = replace(PARAMS, passes=replace(PARAMS.passes, pooled_min_inliers=0),
                second_look=replace(PARAMS.second_look, candidates=2, from_inliers=0, precheck_min_inliers=30))
    matched: list[int] = []

    def counting(a: Feats, b: NodeFeatures) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        matched.append(len(b.keypoints))
        return match_by_id(a, b)

    full = FullResolution(s, m)
    r = VisualLocalizer(m, p, s.extract, s.describe, few,
                        second_look=SecondLook(m, p, full.extract, s.describe, counting, SMALLER)
                        ).localize_global(0, IMG, depth, K)
    assert r.accepted and r.stop_reason.startswith("looked at again at full resolution") and matched
    # the keyframes' full-resolution descriptors scrambled: the pre-check refuses both, no match runs
    full.feats = [replace(f, descriptors=f.descriptors[np.random.default_rng(k).permutation(len(f.descriptors))])
                  for k, f in enumerate(full.feats)]
    matched.clear()
    r2 = VisualLocalizer(m, p, s.extract, s.describe, few,
                         second_look=SecondLook(m, p, full.extract, s.describe, counting, SMALLER)
                         ).localize_global(0, IMG, depth, K)
    assert not r2.accepted and not matched
    assert "no candidate passed the full-resolution pre-check" in r2.stop_reason
    assert any(a.reason.startswith("full-resolution pre-check") for a in r2.attempts)
    assert r2.timings_ms["second_look"] > 0


def test_the_looks_guided_matches_keep_the_global_mutual_rule_that_lls_first_look_drops() -> None:
    """LL's first look matches by the prior without the global-mutual rule
    (`local_search.guided_global_mutual` off); the second look's denser features keep it."""
    m = _with_images(make_map([0.0, 1.0, 2.0, 3.0]))
    s = Scene(m)
    assert not PARAMS.local_search.guided_global_mutual
    look = SecondLook(m, PARAMS, FullResolution(s, m).extract, s.describe, match_by_id, SMALLER)
    assert look.params.local_search.guided_global_mutual and look.local.verifier.map.features is look.features
