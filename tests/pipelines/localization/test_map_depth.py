"""Verification and refinement with the map's depth where the live depth is missing (issue #43),
GL's candidate shortlist, and the inverse of a PnP result."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from litevloc.base import geometry as g
from litevloc.base.params.localization import RefineParams
from litevloc.pipelines.localization.prior import Prior
from litevloc.pipelines.localization.refine import KeyframeObservations, refine_pose
from litevloc.pipelines.localization.vloc import VisualLocalizer
from litevloc.pipelines.pnp import PnpResult, inverse_result
from litevloc.pipelines.topomap.types import NodeFeatures, TopoMap
from tests.pipelines.localization.test_refine import KF_POSES, T_MAP_LIVE
from tests.pipelines.localization.test_refine import K as K_REFINE
from tests.pipelines.localization.test_vloc import IMG, PARAMS, POINTS, K, Scene, make_map, pose


def _with_map_depth(m: TopoMap) -> TopoMap:
    """The map with each keyframe's depth at its keypoints (the points' z in the keyframe)."""
    feats = []
    for f, T in zip(m.features, m.T_map_camera, strict=True):
        ids = f.descriptors[:, 0].astype(np.int64)
        z = g.transform_points(g.invert(T), POINTS[ids])[:, 2].astype(np.float32)
        feats.append(NodeFeatures(f.keypoints, f.descriptors, f.scores, f.image_size, z))
    return replace(m, features=feats)


def _holes(depth: NDArray[np.float32], keep_cols: int) -> NDArray[np.float32]:
    """Live depth only in the leftmost `keep_cols` columns (a registration gap, a black surface)."""
    out = np.full_like(depth, np.nan)
    out[:, :keep_cols] = depth[:, :keep_cols]
    return out


def test_gl_verifies_and_confirms_with_map_depth_where_live_depth_is_missing() -> None:
    m = _with_map_depth(make_map([0.0, 0.5, 1.0, 1.5]))
    s = Scene(m)
    T_true = pose(0.7, 4.0)
    depth = _holes(s.look(T_true, vpr_best=1), 8)
    assert np.isfinite(depth).mean() < 0.1
    on_params = replace(PARAMS, verify=replace(PARAMS.verify, map_depth=True))
    on = VisualLocalizer(m, on_params, s.extract, s.describe, s.match).localize_global(0, IMG, depth, K)
    assert on.accepted, on.reason
    assert len(on.keyframes) >= 2  # the second keyframe confirmed it through map-depth terms
    dt, dr = g.relative_pose_error(on.T_map_camera, T_true)
    assert dt < 0.01 and dr < 0.3
    off = VisualLocalizer(m, replace(PARAMS, verify=replace(PARAMS.verify, map_depth=False),
                                     passes=replace(PARAMS.passes, map_depth=False)), s.extract, s.describe,
                          s.match)
    r = off.localize_global(0, IMG, depth, K)
    assert not r.accepted and all("too few matches with depth" in a.reason for a in r.attempts)


def test_the_map_depth_fallback_verifies_again_only_what_live_depth_refused() -> None:
    """`passes.map_depth`: GL and LL refused for want of live depth are verified again with the
    map's depth (accepted, saying so); a frame that live depth verifies is not verified twice."""
    m = _with_map_depth(make_map([0.0, 0.5, 1.0, 1.5]))
    s = Scene(m)
    T_true = pose(0.7, 4.0)
    full = s.look(T_true, vpr_best=1)
    holes = _holes(full, 8)
    loc = VisualLocalizer(m, PARAMS, s.extract, s.describe, s.match)  # the fallback is on by default
    near = Prior(pose(0.75), fused=False)
    for r in (loc.localize_global(0, IMG, holes, K), loc.localize_local(0, IMG, holes, K, near)):
        assert r.accepted and "verified again with the map's depth" in r.stop_reason, (r.mode, r.reason)
        assert any("too few matches with depth" in a.reason for a in r.attempts)  # the first pass's refusal kept
        assert g.relative_pose_error(r.T_map_camera, T_true)[0] < 0.01
    assert not loc.params.verify.map_depth  # for that query alone
    # a repeated place could pass its gate
    stale = loc.localize_local(0, IMG, holes, K, Prior(pose(0.75), 10.0, fused=False))
    assert not stale.accepted and "map's depth" not in stale.stop_reason
    r = loc.localize_global(0, IMG, full, K)
    assert r.accepted and "map's depth" not in r.stop_reason
    off = VisualLocalizer(m, replace(PARAMS, passes=replace(PARAMS.passes, map_depth=False)), s.extract, s.describe,
                          s.match)
    assert not off.localize_global(0, IMG, holes, K).accepted
    assert not off.localize_local(0, IMG, holes, K, Prior(pose(0.75), fused=False)).accepted


def test_refinement_with_keyframe_points_only_reaches_the_truth() -> None:
    rng = np.random.default_rng(3)
    obs = []
    for k, T_map_kf in enumerate(KF_POSES):  # keyframe points (map depth) seen in the live image, no live depth
        uv = rng.uniform([20, 20], [620, 460], size=(60, 2))
        P = g.backproject_pixels(K_REFINE, uv, rng.uniform(1.0, 3.5, 60))
        y = g.transform_points(g.invert(T_MAP_LIVE) @ T_map_kf, P)
        px_live = g.project(K_REFINE, y) + rng.normal(0, 0.3, (60, 2))
        obs.append(KeyframeObservations(k, np.zeros((0, 3)), np.zeros((0, 2)), K_REFINE, T_map_kf, None,
                                        P, px_live, K_REFINE))
    T0 = T_MAP_LIVE @ g.make_T(g.so3_exp(np.array([0.01, -0.02, 0.015])), np.array([0.03, -0.02, 0.04]))
    res = refine_pose(T0, obs, RefineParams(gate_px=40.0))
    assert res.accepted, res.reason
    assert res.consistent_keyframes == 3 and res.n_inliers > 150
    dt, dr = g.relative_pose_error(res.T_map_camera, T_MAP_LIVE)
    assert dt < 0.005 and dr < 0.1


def test_gl_reranks_a_shortlist_deeper_than_what_it_verifies() -> None:
    m = make_map([0.0, 1.0, 2.0, 3.0, 4.0, 5.0])
    s = Scene(m)
    depth = s.look(pose(4.9), vpr_best=0)
    s.vpr = np.array([1.0, 0.9, 0.8, 0.7, 0.6, 0.5], np.float32)  # the right places rank last
    s.broken_nodes = {0, 1, 2}
    shallow = VisualLocalizer(m, replace(PARAMS, global_search=replace(PARAMS.global_search, top_k=2, rerank_depth=0)),
                              s.extract, s.describe, s.match)
    r = shallow.localize_global(0, IMG, depth, K)
    assert not r.accepted and set(r.candidates) == {0, 1}
    deep = VisualLocalizer(m, replace(PARAMS, global_search=replace(PARAMS.global_search, top_k=2, rerank_depth=6)),
                           s.extract, s.describe, s.match)
    r = deep.localize_global(0, IMG, depth, K)
    assert r.accepted and set(r.candidates) <= {3, 4, 5} and r.ref_node in (4, 5)


def test_inverse_result_inverts_the_pose_and_carries_the_covariance() -> None:
    rng = np.random.default_rng(1)
    A = g.make_T(g.so3_exp(rng.normal(size=3) * 0.5), rng.normal(size=3))
    L = rng.normal(size=(6, 6)) * 1e-3
    res = inverse_result(PnpResult(True, "ok", A, np.arange(50), 80, 0.7, L @ L.T))
    assert res.T_target_source is not None and res.covariance is not None
    np.testing.assert_allclose(res.T_target_source @ A, np.eye(4), atol=1e-12)
    # (A exp(d))^-1 = A^-1 exp(d') with d' linear in d: the covariance maps with that Jacobian
    J = np.zeros((6, 6))
    for i in range(6):
        d = np.zeros(6)
        d[i] = 1e-6
        E = g.invert(res.T_target_source) @ g.invert(A @ g.make_T(g.so3_exp(d[3:]), d[:3]))
        J[:, i] = np.r_[E[:3, 3], g.so3_log(E[:3, :3])] / 1e-6
    np.testing.assert_allclose(res.covariance, J @ (L @ L.T) @ J.T, rtol=1e-4, atol=1e-12)
    assert (res.n_inliers, res.n_matches, res.accepted) == (50, 80, True)
