from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from litevloc.base import geometry as g
from litevloc.base.params.navigation import GoalParams, TrackerParams
from litevloc.pipelines.navigation.graph import NavigationError, shortest_path
from litevloc.pipelines.navigation.planner import localize_goal
from litevloc.pipelines.navigation.tracker import SubgoalTracker
from tests.pipelines.localization.test_vloc import K, match_by_id, observe, pose
from tests.pipelines.localization.test_vloc import make_map as make_vloc_map


def grid_map(edges: list[tuple[int, int, float]], n: int):  # type: ignore[no-untyped-def]
    m = make_vloc_map([float(i) for i in range(n)])
    import dataclasses

    e = np.array([(a, b) for a, b, _ in edges], np.int64).reshape(-1, 2)
    w = np.array([c for _, _, c in edges], np.float32)
    return dataclasses.replace(m, conn_edges=e, conn_metres=w)


def test_dijkstra_prefers_short_total_length() -> None:
    m = grid_map([(0, 1, 1.0), (1, 3, 1.0), (0, 2, 0.5), (2, 3, 5.0), (3, 4, 1.0)], 5)
    path, length = shortest_path(m, 0, 4)
    assert path == [0, 1, 3, 4] and np.isclose(length, 3.0)
    assert shortest_path(m, 2, 2) == ([2], 0.0)
    m2 = grid_map([(0, 1, 1.0)], 3)
    with pytest.raises(NavigationError, match="no path"):
        shortest_path(m2, 0, 2)


def test_tracker_advances_replans_and_reaches() -> None:
    m = grid_map([(0, 1, 1.0), (1, 2, 1.0), (2, 3, 1.0)], 4)
    tr = SubgoalTracker(m, TrackerParams(reach_m=0.3, stray_m=1.5))
    st = tr.set_goal(3, np.array([0.1, 0, 0]))
    assert st.state == "planned" and st.path == (0, 1, 2, 3)
    st = tr.update(np.array([0.05, 0, 0]))
    assert st.subgoal == 1
    st = tr.update(np.array([2.0, 0, 3.0]))  # strayed 3 m off the path
    assert tr.replans == 1 and st.state == "planned"
    for x in (1.0, 2.0, 3.0):
        st = tr.update(np.array([x, 0, 0]))
    assert st.state == "reached"


def test_goal_localization_verifies_geometry() -> None:
    m = make_vloc_map([0.0, 1.0, 2.0, 3.0])
    feats, _ = observe(pose(2.1))
    desc = np.zeros(4, np.float32)
    desc[0] = 1.0
    desc[2] = 0.9
    res = localize_goal(feats, desc / np.linalg.norm(desc), K, m, match_by_id, GoalParams(top_k=4))
    assert res.reason == "ok" and len(res.candidates) == 4
    assert res.node == max(res.candidates, key=lambda c: c[2])[0]  # the best-verified candidate wins
    behind = g.make_T(g.so3_exp(np.array([0, np.pi, 0])), [0.0, 0.0, 0.0])
    far, _ = observe(behind)  # looks away from every map point: nothing verifies
    res2 = localize_goal(far, desc / np.linalg.norm(desc), K, m, match_by_id)
    assert res2.node is None and "matches no map place" in res2.reason


def test_tracker_stray_is_measured_from_the_path_segment() -> None:
    from litevloc.pipelines.navigation.graph import segment_distance

    assert np.isclose(segment_distance(np.array([1.0, 1.0, 0]), np.zeros(3), np.array([2.0, 0, 0])), 1.0)
    assert np.isclose(segment_distance(np.array([-1.0, 0, 0]), np.zeros(3), np.array([2.0, 0, 0])), 1.0)
    # nodes 3 m apart: halfway along the segment the robot is 1.5 m from both nodes but on the path
    m = grid_map([(0, 1, 3.0)], 2)
    m = dataclasses.replace(m, T_map_camera=m.T_map_camera.copy())
    m.T_map_camera[1, 0, 3] = 3.0 + m.T_map_camera[0, 0, 3]
    tr = SubgoalTracker(m, TrackerParams(reach_m=0.3, stray_m=1.2, clearance_m=0.0))
    p0 = m.positions[0].copy()
    tr.set_goal(1, p0)
    tr.update(p0)  # node 0 reached
    st = tr.update(p0 + np.array([1.5, 0.3, 0.0]))
    assert st.state == "planned" and tr.replans == 0 and st.subgoal == 1
    st = tr.update(p0 + np.array([1.5, 1.5, 0.0]))  # 1.5 m off the segment
    assert tr.replans == 1


def test_tracker_positions_override_must_match_nodes() -> None:
    m = grid_map([(0, 1, 1.0)], 2)
    with pytest.raises(ValueError, match="positions"):
        SubgoalTracker(m, positions=np.zeros((3, 3)))


def test_shortest_path_handles_zero_length_and_duplicate_edges() -> None:
    m = grid_map([(0, 1, 0.0), (1, 2, 1.0), (1, 2, 3.0), (0, 2, 2.5)], 3)
    path, length = shortest_path(m, 0, 2)
    assert path == [0, 1, 2] and length == pytest.approx(1.0)
    assert shortest_path(m, 1, 0) == ([1, 0], 0.0)


def test_tracker_nearest_node_is_the_brute_force_one() -> None:
    m = grid_map([(i, i + 1, 1.0) for i in range(9)], 10)
    tr = SubgoalTracker(m)
    rng = np.random.default_rng(0)
    for p in rng.uniform(-3, 12, (200, 3)):
        assert tr.nearest_node(p) == int(np.argmin(np.linalg.norm(m.positions - p, axis=1)))


def _depth_map():  # type: ignore[no-untyped-def]
    from tests.pipelines.localization.test_vloc import POINTS

    m = make_vloc_map([0.0, 1.0, 2.0, 3.0])
    feats = []
    for Ti, f in zip(m.T_map_camera, m.features, strict=True):
        pc = g.transform_points(g.invert(Ti), POINTS[f.descriptors[:, 0].astype(np.int64)])
        feats.append(dataclasses.replace(f, depth=pc[:, 2].astype(np.float32)))
    return dataclasses.replace(m, features=feats)


def test_goal_pose_from_keypoint_depth_is_metric() -> None:
    md = _depth_map()
    m = make_vloc_map([0.0, 1.0, 2.0, 3.0])
    T_goal = pose(2.3, yaw_deg=10.0)  # 0.3 m past node 2, turned 10 deg
    goal, _ = observe(T_goal)
    desc = np.zeros(4, np.float32)
    desc[2] = 1.0
    res = localize_goal(goal, desc, K, md, match_by_id, GoalParams(top_k=4))
    assert res.node == 2 and res.T_map_goal is not None and res.pose_inliers > 100  # the keyframe nearest the pose
    np.testing.assert_allclose(res.T_map_goal, T_goal, atol=1e-6)
    # a map without keypoint depth (format 1, or features converted in memory): the node only
    res2 = localize_goal(goal, desc, K, m, match_by_id, GoalParams(top_k=4))
    assert res2.node == max(res2.candidates, key=lambda c: c[2])[0] and res2.T_map_goal is None
    assert res2.reason == "ok"
    # a pose beyond pose_max_m of its keyframe is not trusted: in a map with depth the goal is
    # refused (its node alone can be metres from where the image was taken), not placed on the node
    res3 = localize_goal(goal, desc, K, md, match_by_id, GoalParams(top_k=4, pose_max_m=0.1))
    assert res3.node is None and res3.T_map_goal is None
    strongest = max(res3.candidates, key=lambda c: c[2])[0]
    assert "no metric pose" in res3.reason and f"node {strongest}" in res3.reason
    assert "within 0.1 m" in res3.reason
    node_only = localize_goal(goal, desc, K, md, match_by_id, GoalParams(top_k=4, pose_max_m=0.1, require_pose=False))
    assert node_only.node is not None and node_only.T_map_goal is None and node_only.reason == "ok"


def test_a_goal_pose_inside_a_wall_or_unexplained_at_its_keyframe_is_not_trusted() -> None:
    """A goal 0.3 m / 10 deg from node 2 whose image shares a tenth of the view's keypoints (a
    repeating texture matched, the rest of the scene not): PnP still puts it at node 2's view
    but explains far under a fifth of what node 2 sees there, so the goal is refused; the same
    sparse image 0.7 m and 30 deg from node 2 is placed (the share is only asked of a view at the
    keyframe's own). A full image whose pose falls in an occupied grid cell is refused too."""
    from tests.pipelines.localization.test_vloc import Feats

    md = _depth_map()
    desc = np.zeros(4, np.float32)
    desc[2] = 1.0
    prm = GoalParams(top_k=1, expand_k=0)  # node 2 alone (VPR top)

    def sparse(T: np.ndarray) -> Feats:
        f, _ = observe(T)
        k = np.arange(0, len(f.keypoints), 10)
        return Feats(f.keypoints[k], f.descriptors[k], f.scores[k], f.ids[k])

    near = localize_goal(sparse(pose(2.3, yaw_deg=10.0)), desc, K, md, match_by_id, prm)
    assert near.node is None and near.T_map_goal is None
    assert "no metric pose" in near.reason and "repeating texture" in near.reason and "keyframe 2" in near.reason
    off = localize_goal(sparse(pose(2.3, yaw_deg=10.0)), desc, K, md, match_by_id,
                        dataclasses.replace(prm, pose_min_explained=0.0))
    assert off.node == 2 and off.T_map_goal is not None
    between = localize_goal(sparse(pose(1.3, yaw_deg=30.0)), desc, K, md, match_by_id, prm)
    assert between.reason == "ok" and between.T_map_goal is not None
    np.testing.assert_allclose(between.T_map_goal, pose(1.3, yaw_deg=30.0), atol=1e-6)

    goal, _ = observe(pose(2.3, yaw_deg=10.0))
    cells = np.zeros((4, 4), np.uint8)
    cells[0, 2] = 2  # plane (x, z) = (2.3, 0) lies in row 0, column 2 of a 1 m grid at the origin
    walled = dataclasses.replace(md, grid=dataclasses.replace(md.grid, cells=cells))
    res = localize_goal(goal, desc, K, walled, match_by_id, prm)
    assert res.node is None and "inside an obstacle" in res.reason
    assert localize_goal(goal, desc, K, md, match_by_id, prm).reason == "ok"
    assert localize_goal(goal, desc, K, walled, match_by_id,
                         dataclasses.replace(prm, pose_outside_obstacles=False)).reason == "ok"


def test_goal_that_verifies_at_two_places_is_refused_as_ambiguous() -> None:
    """Node 0 sees a copy of node 2's view (the same poster hung 2 m away): both verify, their
    metric goal poses lie 2 m apart with equal support (top_k=2: VPR ranks node 2, then node 0),
    so the goal is refused and the reason names both nodes; a weak copy (a third of the
    keypoints) does not veto the strong place."""
    md = _depth_map()
    feats = list(md.features)
    feats[0] = feats[2]
    twin = dataclasses.replace(md, features=feats)
    T_goal = pose(2.3, yaw_deg=10.0)
    goal, _ = observe(T_goal)
    desc = np.zeros(4, np.float32)
    desc[2] = 1.0
    res = localize_goal(goal, desc, K, twin, match_by_id, GoalParams(rerank_depth=0, top_k=2, expand_k=0))
    assert res.node is None and res.T_map_goal is None
    assert "ambiguous" in res.reason and "0" in res.reason and "2" in res.reason and "2.0 m apart" in res.reason
    assert "horizontal surface" not in res.reason  # the support spans heights: no floor-tile hint
    # the veto off: a node is chosen as before
    res_off = localize_goal(goal, desc, K, twin, match_by_id,
                            GoalParams(rerank_depth=0, top_k=2, ambiguity_ratio=0, expand_k=0))
    assert res_off.node in (0, 2) and res_off.reason == "ok"
    # a weak copy: node 0 keeps every third keypoint of node 2's view
    f2 = feats[2]
    keep = np.arange(0, len(f2.keypoints), 3)
    weak = dataclasses.replace(f2, keypoints=f2.keypoints[keep], descriptors=f2.descriptors[keep],
                               scores=f2.scores[keep], depth=f2.depth[keep])
    feats[0] = weak
    res_weak = localize_goal(goal, desc, K, dataclasses.replace(md, features=feats), match_by_id,
                             GoalParams(rerank_depth=0, top_k=2, expand_k=0))
    assert res_weak.node == 2 and res_weak.reason == "ok" and res_weak.T_map_goal is not None
    np.testing.assert_allclose(res_weak.T_map_goal, T_goal, atol=1e-6)


def test_covisible_keyframes_are_one_place_not_a_rival() -> None:
    """The twin map again, but the map's covisibility graph links nodes 0 and 2 (it verified
    that the two keyframes see the same scene, as neighbours in a corridor do, whose goal poses
    can still differ by a metre): one place, so the goal is placed on the strongest node."""
    md = _depth_map()
    feats = list(md.features)
    feats[0] = feats[2]
    twin = dataclasses.replace(md, features=feats)
    linked = dataclasses.replace(twin, covis_edges=np.array([[0, 2]], np.int64), covis_inliers=np.array([50], np.int32),
                                 covis_weight=np.array([0.5], np.float32))
    T_goal = pose(2.3, yaw_deg=10.0)
    goal, _ = observe(T_goal)
    desc = np.zeros(4, np.float32)
    desc[2] = 1.0
    alone = GoalParams(rerank_depth=0, top_k=2, expand_k=0)
    assert localize_goal(goal, desc, K, twin, match_by_id, alone).node is None  # not linked: refused
    res = localize_goal(goal, desc, K, linked, match_by_id, GoalParams(rerank_depth=0, top_k=2, expand_k=0))
    assert res.node in (0, 2) and res.reason == "ok" and res.T_map_goal is not None


def test_goal_params_validate_the_ambiguity_veto() -> None:
    with pytest.raises(ValueError, match="ambiguity_ratio"):
        GoalParams(ambiguity_ratio=0.5)
    with pytest.raises(ValueError, match="agree_m"):
        GoalParams(agree_m=0.0)


def ring_map(n: int = 12, radius: float = 3.0):  # type: ignore[no-untyped-def]
    """n keyframes on a ring, every camera facing along it counter-clockwise (a corridor
    mapped one way round), edges between neighbours."""
    m = make_vloc_map([float(i) for i in range(n)])
    T = np.tile(np.eye(4), (n, 1, 1))
    for k in range(n):
        a = 2 * np.pi * k / n
        z = np.array([-np.sin(a), 0.0, np.cos(a)])  # optical axis: the ring's tangent
        y = np.array([0.0, 1.0, 0.0])
        T[k, :3, :3] = np.column_stack([np.cross(y, z), y, z])
        T[k, :3, 3] = radius * np.array([np.cos(a), 0.0, np.sin(a)])
    e = np.array([(k, (k + 1) % n) for k in range(n)], np.int64)
    w = np.linalg.norm(T[e[:, 0], :3, 3] - T[e[:, 1], :3, 3], axis=1).astype(np.float32)
    return dataclasses.replace(m, T_map_camera=T, conn_edges=e, conn_metres=w)


def test_planner_keeps_to_the_maps_viewing_direction_unless_the_way_back_is_far_shorter() -> None:
    m = ring_map()
    chord = float(m.conn_metres[0])
    here = m.positions[0]
    # node 10 is 2 edges back, 10 edges ahead: with the default cost (10x) the way ahead wins
    tr = SubgoalTracker(m, TrackerParams())
    st = tr.set_goal(10, here)
    assert st.path == tuple(range(11)) and np.isclose(st.remaining_m, 10 * chord, rtol=1e-5)
    # node 11: 1 edge back (cost 10) vs 11 ahead: back, and its length is in metres
    st = tr.set_goal(11, here)
    assert st.path == (0, 11) and np.isclose(st.remaining_m, chord, rtol=1e-5)
    # by length alone (cost 1), back to node 10
    flat = SubgoalTracker(m, TrackerParams(against_view_cost=1.0))
    assert flat.set_goal(10, here).path == (0, 11, 10)
    # a narrower cone: with 179 deg nothing counts as against the views
    assert SubgoalTracker(m, TrackerParams(against_view_deg=179.0)).set_goal(10, here).path == (0, 11, 10)
    for bad in ({"against_view_cost": 0.5}, {"against_view_cost": float("inf")}, {"against_view_deg": 0.0}):
        with pytest.raises(ValueError, match="against_view"):
            TrackerParams(**bad)  # type: ignore[arg-type]


def test_plane_rms_measures_how_flat_a_point_set_is() -> None:
    from litevloc.pipelines.navigation.candidates import plane_rms

    rng = np.random.default_rng(3)
    wall = np.column_stack([rng.uniform(-1, 1, 200), rng.uniform(0, 2, 200), np.full(200, 4.0)])
    tilt = g.so3_exp(np.array([0.3, -0.5, 0.2]))
    assert plane_rms(wall @ tilt.T + [1.0, 2.0, 3.0]) < 1e-9  # any plane, any pose
    noisy = wall + [0.0, 0.0, 0.01] * rng.standard_normal((200, 3))
    assert 0.008 < plane_rms(noisy) < 0.012  # the noise off the plane, in metres
    box = rng.uniform(-0.5, 0.5, (200, 3))
    assert plane_rms(box) > 0.2
    assert np.isnan(plane_rms(box[:2]))


def _sparse_map(n_keep: int):  # type: ignore[no-untyped-def]
    """`_depth_map` with every node's features cut to its first `n_keep` keypoints."""
    md = _depth_map()
    feats = [dataclasses.replace(f, keypoints=f.keypoints[:n_keep], descriptors=f.descriptors[:n_keep],
                                 scores=f.scores[:n_keep], depth=f.depth[:n_keep]) for f in md.features]
    return dataclasses.replace(md, features=feats)


def test_goal_supported_by_one_flat_patch_needs_more_inliers(monkeypatch: pytest.MonkeyPatch) -> None:
    """A goal image whose matches to the best keyframe all lie on one plane (a poster: the same
    picture can hang in another room) verifies a place only with `planar_factor` x
    `min_inliers`; between the two bars it is refused with a reason naming the flat patch.
    The same number of matches spread in depth verifies as before; so do enough flat ones."""
    import tests.pipelines.localization.test_vloc as tv

    T_goal = pose(2.3, yaw_deg=10.0)
    desc = np.zeros(4, np.float32)
    desc[2] = 1.0
    params = GoalParams(rerank_depth=0, top_k=1, min_inliers=40, planar_rms_m=0.03, planar_factor=2.0, expand_k=0)
    # a scene spread in depth: 60 keypoints per keyframe verify (40 <= inliers < 80)
    goal, _ = observe(T_goal)
    res = localize_goal(goal, desc, K, _sparse_map(60), match_by_id, params)
    assert res.node == 2 and res.reason == "ok" and 40 <= res.inliers < 80
    # the same scene flattened onto one wall 6 m in front of the cameras
    flat = tv.POINTS.copy()
    flat[:, 2] = 6.0
    monkeypatch.setattr(tv, "POINTS", flat)
    goal, _ = observe(T_goal)
    res = localize_goal(goal, desc, K, _sparse_map(60), match_by_id, params)
    assert res.node is None and res.T_map_goal is None and 40 <= res.inliers < 80
    assert "flat patch" in res.reason and "node 2" in res.reason and "< 80" in res.reason
    off = localize_goal(goal, desc, K, _sparse_map(60), match_by_id, dataclasses.replace(params, planar_rms_m=0.0))
    assert off.node == 2 and off.reason == "ok"
    many = localize_goal(goal, desc, K, _sparse_map(200), match_by_id, params)
    assert many.node == 2 and many.reason == "ok" and many.inliers >= 80
    np.testing.assert_allclose(many.T_map_goal, T_goal, atol=1e-5)
    for bad in ({"planar_rms_m": -0.01}, {"planar_factor": 0.5}, {"planar_factor": float("nan")}):
        with pytest.raises(ValueError, match="planar"):
            GoalParams(**bad)  # type: ignore[arg-type]


def test_a_goal_matched_on_floor_tiles_alone_verifies_no_place(monkeypatch: pytest.MonkeyPatch) -> None:
    """Every scene point on the floor (1.2 m below the cameras; tiles repeat in every room): the
    goal image gets plenty of essential-matrix and PnP inliers at node 2, yet none of its PnP
    support lies off the floor band, so it verifies no place and is refused naming the tiles
    (`pose_min_distinct`); with the rule off it is placed. The same scene with a third of the
    points lifted onto walls keeps enough support off the floor and is placed at its pose."""
    import tests.pipelines.localization.test_vloc as tv

    T_goal = pose(2.3, yaw_deg=10.0)
    desc = np.zeros(4, np.float32)
    desc[2] = 1.0
    params = GoalParams(rerank_depth=0, top_k=1, expand_k=0)  # pose_min_distinct 10
    floor = tv.POINTS.copy()
    floor[:, 1] = 1.2
    monkeypatch.setattr(tv, "POINTS", floor)
    goal, _ = observe(T_goal)
    res = localize_goal(goal, desc, K, _sparse_map(200), match_by_id, params)
    assert res.node is None and res.T_map_goal is None and res.inliers >= 2 * params.min_inliers
    assert "only floor or ceiling tiles at node 2" in res.reason and "0 of" in res.reason
    off = localize_goal(goal, desc, K, _sparse_map(200), match_by_id, dataclasses.replace(params, pose_min_distinct=0))
    assert off.node == 2 and off.reason == "ok"
    walls = floor.copy()
    walls[::3, 1] = np.random.default_rng(3).uniform(-1.5, 1.0, len(walls[::3]))
    monkeypatch.setattr(tv, "POINTS", walls)
    goal, _ = observe(T_goal)
    res = localize_goal(goal, desc, K, _sparse_map(200), match_by_id, params)
    assert res.node == 2 and res.reason == "ok"
    np.testing.assert_allclose(res.T_map_goal, T_goal, atol=1e-5)
    with pytest.raises(ValueError, match="pose_min_distinct"):
        GoalParams(pose_min_distinct=-1)


def test_a_keyframe_with_too_little_depth_is_posed_with_its_covisible_ones() -> None:
    """Each keyframe keeps mapping depth for a disjoint fortieth of its keypoints, so no single
    keyframe gives the goal image `pose_min_inliers` PnP inliers: the goal verifies best at node 3
    (most essential-matrix inliers) but gets no metric pose there and is refused. Posed from node
    3's and its covisible keyframe's (2) depth points together (`pose_pool_covisible`), it is placed
    at its true pose; nodes 0 and 1, not covisible with node 3, add nothing (cut node 1 and 3's
    depth and it is refused again, though nodes 0 and 2 together would hold enough)."""
    T_goal = pose(2.3, yaw_deg=10.0)
    goal, _ = observe(T_goal)
    desc = np.zeros(4, np.float32)
    desc[2] = 1.0
    md = _depth_map()
    ids = [f.descriptors[:, 0].astype(np.int64) for f in md.features]
    feats = [dataclasses.replace(f, depth=np.where(i % 40 == n, f.depth, np.nan).astype(np.float32))
             for n, (f, i) in enumerate(zip(md.features, ids, strict=True))]
    sparse = dataclasses.replace(md, features=feats)
    params = GoalParams(rerank_depth=0, top_k=4, expand_k=0, pose_min_inliers=60)  # pose_pool_covisible on
    alone = localize_goal(goal, desc, K, sparse, match_by_id, dataclasses.replace(params, pose_pool_covisible=False))
    assert alone.node is None and "no metric pose" in alone.reason
    assert 0 < alone.pose_inliers < params.pose_min_inliers
    pooled = localize_goal(goal, desc, K, sparse, match_by_id, params)
    assert pooled.node == 3 and pooled.reason == "ok" and pooled.pose_inliers >= params.pose_min_inliers
    np.testing.assert_allclose(pooled.T_map_goal, T_goal, atol=1e-5)
    cut = [f if n in (0, 2) else dataclasses.replace(f, depth=np.full_like(f.depth, np.nan))
           for n, f in enumerate(feats)]
    res = localize_goal(goal, desc, K, dataclasses.replace(sparse, features=cut), match_by_id, params)
    assert res.node is None and "no metric pose" in res.reason


def test_a_tiles_only_candidate_is_not_posed_from_its_covisible_ones(monkeypatch: pytest.MonkeyPatch) -> None:
    """A third of the scene on walls, the rest on the floor. Node 2 matches the goal best but keeps
    mapping depth for its floor points only (its own support: tiles alone); its covisible nodes 1
    and 3 hold wall points but too few matches to verify. Pooling node 2 with them would give it a
    pose; its tile matches, a tile off in a real building, must not lead the pool, so the goal is
    refused as matching only tiles."""
    import tests.pipelines.localization.test_vloc as tv

    scene = tv.POINTS.copy()
    scene[:, 1] = 1.2
    scene[::3, 1] = np.random.default_rng(3).uniform(-1.5, 1.0, len(scene[::3]))
    monkeypatch.setattr(tv, "POINTS", scene)
    T_goal = pose(2.3, yaw_deg=10.0)
    goal, _ = observe(T_goal)
    desc = np.zeros(4, np.float32)
    desc[2] = 1.0
    md = _depth_map()
    feats = []
    for n, f in enumerate(md.features):
        wall = f.descriptors[:, 0].astype(np.int64) % 3 == 0
        if n == 2:
            feats.append(dataclasses.replace(f, depth=np.where(wall, np.nan, f.depth).astype(np.float32)))
        else:  # 20 wall keypoints each: too few matches to verify
            k = np.flatnonzero(wall)[20 * (n % 2): 20 * (n % 2) + 20]
            feats.append(dataclasses.replace(f, keypoints=f.keypoints[k], descriptors=f.descriptors[k],
                                             scores=f.scores[k], depth=f.depth[k]))
    res = localize_goal(goal, desc, K, dataclasses.replace(md, features=feats), match_by_id,
                        GoalParams(rerank_depth=0, top_k=4, expand_k=0))
    assert res.node is None and res.T_map_goal is None
    assert "only floor or ceiling tiles at node 2" in res.reason


def test_a_verified_keyframe_without_a_pose_is_stood_for_by_a_posed_one_nearby() -> None:
    """Node 3 holds the most essential-matrix inliers but no mapping depth, so it gives no pose and
    the goal is refused (`pose_fallback_m` 0); with 1.5 the strongest posed candidate within 1.5 m of
    node 3 (node 2, 1 m away) stands for it and the goal is placed at its true pose; within 0.5 m
    there is none and the goal is refused as before."""
    T_goal = pose(2.3, yaw_deg=10.0)
    goal, _ = observe(T_goal)
    desc = np.zeros(4, np.float32)
    desc[2] = 1.0
    md = _depth_map()
    feats = [dataclasses.replace(f, depth=np.full_like(f.depth, np.nan)) if n == 3 else f
             for n, f in enumerate(md.features)]
    m = dataclasses.replace(md, features=feats)
    params = GoalParams(rerank_depth=0, top_k=4, expand_k=0, pose_pool_covisible=False)
    off = localize_goal(goal, desc, K, m, match_by_id, dataclasses.replace(params, pose_fallback_m=0.0))
    assert off.node is None and "verifies at node 3" in off.reason and "no metric pose" in off.reason
    res = localize_goal(goal, desc, K, m, match_by_id, dataclasses.replace(params, pose_fallback_m=1.5))
    assert res.node == 2 and res.reason == "ok"
    np.testing.assert_allclose(res.T_map_goal, T_goal, atol=1e-5)
    near = localize_goal(goal, desc, K, m, match_by_id, dataclasses.replace(params, pose_fallback_m=0.5))
    assert near.node is None and "no metric pose" in near.reason
    with pytest.raises(ValueError, match="pose_fallback_m"):
        GoalParams(pose_fallback_m=-1.0)


def test_horizontal_share_is_the_part_of_a_support_on_one_horizontal_surface() -> None:
    """A corridor view's support: 80 points on the floor (heights within 1 cm), 20 on a wall
    (heights spread over 2 m) -> 0.8 along the map's up; the same points with up along x
    (a wall's normal) share no horizontal band -> small; no points -> NaN."""
    from litevloc.pipelines.navigation.candidates import horizontal_share

    rng = np.random.default_rng(0)
    floor = np.c_[rng.uniform(0, 10, 80), rng.uniform(-1, 1, 80), rng.uniform(-0.005, 0.005, 80)]
    wall = np.c_[rng.uniform(0, 10, 20), np.full(20, 1.0), rng.uniform(0.5, 2.5, 20)]
    # any place and heading in the map
    pts = np.vstack([floor, wall]) @ g.so3_exp(np.array([0.0, 0.0, 0.3])).T + [3.0, -2.0, 0.0]
    assert horizontal_share(pts, np.array([0.0, 0.0, 1.0])) == pytest.approx(0.8, abs=0.02)
    assert horizontal_share(np.vstack([floor, wall]), np.array([1.0, 0.0, 0.0])) < 0.1
    assert np.isnan(horizontal_share(np.zeros((0, 3)), np.array([0.0, 0.0, 1.0])))


def test_keyframes_near_the_strongest_candidate_are_verified_too() -> None:
    """Retrieval ranks the keyframe that saw the goal's view last (top_k=1 takes node 0, 2.1 m
    from the goal's camera); the keyframes near node 0 facing its way are verified as well, and
    node 2, whose view the goal shares most, wins."""
    m = make_vloc_map([0.0, 1.0, 2.0, 3.0])
    feats, _ = observe(pose(2.1))
    desc = np.zeros(4, np.float32)
    desc[0] = 1.0
    alone = localize_goal(feats, desc, K, m, match_by_id,
                          GoalParams(rerank_depth=0, top_k=1, min_inliers=8, expand_k=0))
    assert [c[0] for c in alone.candidates] == [0]
    res = localize_goal(feats, desc, K, m, match_by_id,
                        GoalParams(rerank_depth=0, top_k=1, min_inliers=8, expand_m=2.5))
    assert [c[0] for c in res.candidates] == [0, 1, 2]  # node 3 is 3 m away: not within expand_m
    assert res.node == 2 and res.reason == "ok"
    with pytest.raises(ValueError, match="expand"):
        GoalParams(expand_m=0.0)


def test_default_bar_verifies_a_goal_with_35_inliers_spread_in_depth() -> None:
    """A goal image that matches its true place with 35 essential-matrix inliers spread in depth
    (a plain room seen from a new spot) is placed under the default `min_inliers` (25); 22 are not
    enough."""
    T_goal = pose(2.3, yaw_deg=10.0)
    desc = np.zeros(4, np.float32)
    desc[2] = 1.0
    params = dataclasses.replace(GoalParams(), top_k=1, expand_k=0)
    goal, _ = observe(T_goal)
    res = localize_goal(goal, desc, K, _sparse_map(48), match_by_id, params)  # 35 inliers
    assert res.node == 2 and res.reason == "ok" and 30 <= res.inliers < 40
    np.testing.assert_allclose(res.T_map_goal, T_goal, atol=1e-5)
    few = localize_goal(goal, desc, K, _sparse_map(26), match_by_id, params)  # 22 inliers
    assert few.node is None and "matches no map place" in few.reason


def test_floor_tiles_do_not_make_a_goal_ambiguous_where_the_rest_of_its_support_singles_out_one_place() -> None:
    """Three places verify a goal image: node 1's and node 3's PnP support lies wholly on the floor
    (tiles repeat, and shifted by a tile they fit 1-2 m off), node 2's spans the scene. By PnP
    support node 1 (most essential inliers) has a rival within x2 (node 2): ambiguous. Counting
    only support off the floor band, node 2's place alone holds any: it is chosen. With fewer than
    `pose_min_inliers` such points, or the rule off (`ambiguity_band_m` 0), the goal stays refused."""
    from litevloc.pipelines.navigation.candidates import Candidate
    from litevloc.pipelines.navigation.places import unambiguous

    m = make_vloc_map([0.0, 1.0, 2.0, 3.0])  # up = -y of the map; no keyframes covisible
    m = dataclasses.replace(m, covis_edges=np.zeros((0, 2), np.int64), covis_inliers=np.zeros(0, np.int32),
                            covis_weight=np.zeros(0, np.float32))
    rng = np.random.default_rng(1)

    def cand(node: int, x_goal: float, inliers: int, pts_map: np.ndarray) -> Candidate:
        T = m.T_map_camera[node]
        return Candidate(node, 0.5, inliers, pose(x_goal), len(pts_map), 0.0, (pts_map - T[:3, 3]) @ T[:3, :3])

    def floor(n: int) -> np.ndarray:
        return np.c_[rng.uniform(-3, 3, n), np.full(n, 1.2) + rng.uniform(-0.005, 0.005, n), rng.uniform(3, 8, n)]

    def scene(n: int) -> np.ndarray:
        return np.c_[rng.uniform(-3, 3, n), rng.uniform(-1.5, 1.2, n), rng.uniform(3, 8, n)]

    tiles, place, tiles2 = cand(1, 1.0, 100, floor(90)), cand(2, 2.2, 90, scene(70)), cand(3, 3.5, 60, floor(40))
    cands = [tiles, place, tiles2]
    params = GoalParams()
    best, refusal = unambiguous(m, cands, cands, tiles, params, ())
    assert refusal is None and best is place
    off = dataclasses.replace(params, ambiguity_band_m=0.0)
    assert unambiguous(m, cands, cands, tiles, off, ())[1] is not None
    thin = cand(2, 2.2, 90, np.vstack([floor(60), scene(params.pose_min_inliers - 2)]))
    res = unambiguous(m, [tiles, thin, tiles2], [tiles, thin, tiles2], tiles, params, ())[1]
    assert res is not None and "ambiguous" in res.reason and "horizontal surface" in res.reason
    # the singled-out place must hold a verified candidate
    assert unambiguous(m, cands, [tiles, tiles2], tiles, params, ())[1] is not None


def test_a_place_gives_the_goal_its_best_supported_pose() -> None:
    """Node 1 verifies the goal (35 essential inliers) with a weak PnP pose 2 m off; node 2, its
    covisible neighbour (one place), did not verify (a flat support needs more) but its pose has
    three times the PnP support and lies where the image was taken: the goal gets node 2's pose,
    and node 2, the place's keyframe nearest that pose, as its node."""
    from litevloc.pipelines.navigation.candidates import Candidate
    from litevloc.pipelines.navigation.places import unambiguous

    m = make_vloc_map([0.0, 1.0, 2.0, 3.0])  # consecutive keyframes covisible
    weak = Candidate(1, 0.5, 35, pose(4.0), 20)
    strong = Candidate(2, 0.5, 30, pose(2.0), 60)
    chosen, refusal = unambiguous(m, [weak, strong], [weak], weak, GoalParams(), ())
    assert refusal is None and chosen.node == 2 and chosen.T_map_goal is strong.T_map_goal
    # node 1's pose is the best supported; node 2's keyframe stands nearer to it: pose 1's, node 2
    far_kf = Candidate(1, 0.5, 30, pose(2.1), 60)
    near_kf = Candidate(2, 0.5, 35, pose(4.0), 20)
    chosen, _ = unambiguous(m, [near_kf, far_kf], [near_kf], near_kf, GoalParams(), ())
    assert chosen.node == 2 and chosen.T_map_goal is far_kf.T_map_goal


def test_a_place_gives_the_goal_the_pose_most_of_its_support_agrees_with() -> None:
    """Three covisible keyframes are one place: the strongest PnP (47 inliers) puts the goal 2 m
    off, the two others (39 and 30) agree where the image was taken: the goal gets the pose of
    the stronger of the two (office room_03: 3.8 m off on the strongest, 4-8 cm on the others)."""
    from litevloc.pipelines.navigation.candidates import Candidate
    from litevloc.pipelines.navigation.places import unambiguous

    m = make_vloc_map([0.0, 1.0, 2.0, 3.0])  # consecutive keyframes covisible
    off = Candidate(1, 0.5, 56, pose(4.0), 47)
    right = Candidate(2, 0.5, 52, pose(2.0), 39)
    also = Candidate(0, 0.5, 43, pose(2.05), 30)
    chosen, refusal = unambiguous(m, [off, right, also], [off, right, also], off, GoalParams(), ())
    assert refusal is None and chosen.T_map_goal is right.T_map_goal and chosen.node == 2
    # the pose with most agreeing support (2.3: agrees with 2.0 and 2.6) stands for its group; the
    # goal gets that group's strongest pose (2.0), not the middle one
    middle = Candidate(2, 0.5, 52, pose(2.3), 25)
    strong = Candidate(1, 0.5, 56, pose(2.0), 40)
    far = Candidate(0, 0.5, 43, pose(2.6), 30)
    chosen, _ = unambiguous(m, [strong, middle, far], [strong, middle, far], strong, GoalParams(), ())
    assert chosen.T_map_goal is strong.T_map_goal


def test_candidate_poses_agree_along_the_floor() -> None:
    """Two goal poses 0.3 m apart on the floor and 0.5 m apart in height (PnP's least certain
    axis; the map's up is -y) are one spot to drive to; 0.6 m apart on the floor they are two."""
    from litevloc.pipelines.navigation.candidates import Candidate
    from litevloc.pipelines.navigation.places import group_places

    to_plane = make_vloc_map([0.0, 1.0]).grid.to_plane  # the floor: x, z
    a = Candidate(0, 0.5, 40, pose(1.0), 40)
    high = pose(1.3)
    high[1, 3] = -0.5
    b = Candidate(1, 0.5, 35, high, 30)
    assert len(group_places([a, b], 0.5, 20.0, to_plane)) == 1
    c = Candidate(1, 0.5, 35, pose(1.6), 30)
    assert len(group_places([a, c], 0.5, 20.0, to_plane)) == 2


def test_goal_retrieval_reorders_the_place_descriptors_candidates_by_local_matches() -> None:
    """The place descriptor ranks node 2, the keyframe that shares the goal's view, last; the
    others keep 20 keypoints each (too few to verify). With `top_k` 1 the VPR order (the default,
    `rerank_depth` 0) verifies node 0 only and refuses the goal; re-ranked by mutual nearest
    neighbours node 2 comes first and the goal is placed there, at its metric pose."""
    md = _depth_map()
    feats = [f if k == 2 else dataclasses.replace(f, keypoints=f.keypoints[:20], descriptors=f.descriptors[:20],
                                                  scores=f.scores[:20], depth=f.depth[:20])
             for k, f in enumerate(md.features)]
    sparse = dataclasses.replace(md, features=feats)
    T_goal = pose(2.3, yaw_deg=10.0)
    goal, _ = observe(T_goal)
    desc = np.array([1.0, 0.8, 0.1, 0.6], np.float32)  # VPR order 0, 1, 3, 2
    params = GoalParams(top_k=1, expand_k=0, rerank_depth=20)
    res = localize_goal(goal, desc, K, sparse, match_by_id, params)
    assert [c[0] for c in res.candidates] == [2] and res.node == 2 and res.reason == "ok"
    np.testing.assert_allclose(res.T_map_goal, T_goal, atol=1e-5)
    off = localize_goal(goal, desc, K, sparse, match_by_id, dataclasses.replace(params, rerank_depth=0))
    assert [c[0] for c in off.candidates] == [0] and off.node is None and "no map place" in off.reason
    shallow = localize_goal(goal, desc, K, sparse, match_by_id, dataclasses.replace(params, rerank_depth=3))
    assert [c[0] for c in shallow.candidates] == [0]  # node 2 is 4th by VPR: beyond the re-ranked depth
    with pytest.raises(ValueError, match="rerank"):
        GoalParams(rerank_depth=-1)


def test_tracker_leads_the_long_way_the_mapping_pass_drove_between_consecutive_keyframes() -> None:
    """Consecutive keyframes 3 m apart on either side of a wall 7 m long (the rooms between them
    covered by other keyframes): their edge holds the 14 m the mapping pass drove. The way round
    the wall's end, ~10 m longer than the straight line, is beyond `leg_detour_m` of the straight
    line but not of the edge's own length: the robot is sent round, not at the wall (a floor
    building's robot dithered 30 s in front of it and gave up)."""
    from litevloc.pipelines.topomap.types import OccupancyGrid

    r = 0.1
    cells = np.full((80, 80), OccupancyGrid.FREE, np.uint8)  # 8 x 8 m, cell (i, j) at x = j r, y = i r
    cells[0, :] = cells[-1, :] = cells[:, 0] = cells[:, -1] = OccupancyGrid.OCCUPIED
    cells[:70, 39:41] = OccupancyGrid.OCCUPIED  # wall x = 3.9-4.1 m from y = 0 to 7 m
    grid = OccupancyGrid(cells, np.zeros(2), r, np.array([0, 0, 1.0]), np.eye(3)[:2])
    pos = np.array([[2.5, 1.0, 0.3], [5.5, 1.0, 0.3]])
    for driven, expect_turns in ((14.0, True), (3.0, False)):
        m = dataclasses.replace(grid_map([(0, 1, driven)], 2), grid=grid)
        tr = SubgoalTracker(m, TrackerParams(reach_m=0.3, stray_m=1.5), positions=pos)
        tr.set_goal(1, pos[0])
        st = tr.update(pos[0])
        assert st.subgoal == 1 and (st.via is not None) == expect_turns, (driven, st)
        if expect_turns:
            assert st.via is not None and st.via[1] > 5.0 and st.remaining_m > 12.0  # up towards the wall's end


def test_tracker_plans_from_the_nearest_node_not_behind_a_wall() -> None:
    """The robot 0.3 m before a wall, a node 0.5 m beyond it and one 1.1 m back in its own room:
    the plan starts from its room's node (from the node behind the wall, a robot that had reached
    a goal in a room was sent at the wall and gave up)."""
    from litevloc.pipelines.topomap.types import OccupancyGrid

    r = 0.1
    cells = np.full((60, 60), OccupancyGrid.FREE, np.uint8)  # 6 x 6 m, cell (i, j) at x = j r, y = i r
    cells[:30, 29:31] = OccupancyGrid.OCCUPIED  # wall x = 2.9-3.1 m from y = 0 to 3 m
    grid = OccupancyGrid(cells, np.zeros(2), r, np.array([0, 0, 1.0]), np.eye(3)[:2])
    pos = np.array([[3.1, 1.0, 0.3], [1.5, 1.0, 0.3], [1.5, 4.0, 0.3]])
    m = dataclasses.replace(grid_map([(0, 2, 4.0), (1, 2, 3.0)], 3), grid=grid)
    tr = SubgoalTracker(m, TrackerParams(reach_m=0.3, stray_m=1.5), positions=pos)
    robot = np.array([2.6, 1.0, 0.3])
    assert tr.nearest_node(robot) == 0 and tr.start_node(robot) == 1
    assert tr.set_goal(2, robot).path[0] == 1
    open_grid = dataclasses.replace(m, grid=dataclasses.replace(grid, cells=np.full_like(cells, OccupancyGrid.FREE)))
    assert SubgoalTracker(open_grid, TrackerParams(reach_m=0.3, stray_m=1.5), positions=pos).start_node(robot) == 0


def test_tracker_leads_round_a_wall_to_a_node_it_cannot_reach_straight() -> None:
    """Two nodes 3 m apart on either side of a wall that ends 1 m above them (a door to go out
    of first): the subgoal stays the node, but the robot is sent along the grid path's turns
    past the wall's end, one after the other, then to the node itself."""
    from litevloc.pipelines.topomap.types import OccupancyGrid

    r = 0.1
    cells = np.full((60, 60), OccupancyGrid.FREE, np.uint8)  # 6 x 6 m, cell (i, j) at x = j r, y = i r
    cells[0, :] = cells[-1, :] = cells[:, 0] = cells[:, -1] = OccupancyGrid.OCCUPIED
    cells[:30, 29:31] = OccupancyGrid.OCCUPIED  # wall x = 2.9-3.1 m from y = 0 to 3 m
    grid = OccupancyGrid(cells, np.zeros(2), r, np.array([0, 0, 1.0]), np.eye(3)[:2])
    m = dataclasses.replace(grid_map([(0, 1, 3.0)], 2), grid=grid)
    pos = np.array([[1.5, 2.0, 0.3], [4.5, 2.0, 0.3]])
    tr = SubgoalTracker(m, TrackerParams(reach_m=0.3, stray_m=1.5), positions=pos)
    tr.set_goal(1, pos[0])
    st = tr.update(pos[0])  # node 0 reached: on to node 1, behind the wall
    assert st.subgoal == 1 and st.via is not None and st.via[1] > 3.0  # first up past the wall's end
    assert st.remaining_m > 3.0 + 0.8  # measured along the turns (2 x 1.9 m and the way across)
    turns = []
    while st.via is not None and len(turns) < 10:
        turns.append(st.via)
        st = tr.update(np.array(st.via))  # the robot arrives at each turn in turn
    assert st.state == "planned" and st.via is None and st.subgoal == 1 and tr.replans == 0
    assert 2 <= len(turns) < 10 and all(t[1] > 3.0 for t in turns)
    assert tr.update(pos[1]).state == "reached"
    # a desk corner 0.2 m beside the straight line (within the robot's radius, not on the line):
    # left to the local planner, no turns
    desk = cells.copy()
    desk[:30, 29:31] = OccupancyGrid.FREE
    desk[21:26, 28:31] = OccupancyGrid.OCCUPIED  # y = 2.1-2.6 m, the line runs at y = 2.0 m
    near = SubgoalTracker(dataclasses.replace(m, grid=dataclasses.replace(grid, cells=desk)),
                          TrackerParams(reach_m=0.3, stray_m=1.5), positions=pos)
    near.set_goal(1, pos[0])
    assert near.update(pos[0]).via is None
    # off, or a wall with no way round within leg_detour_m: the node itself
    off = SubgoalTracker(m, TrackerParams(reach_m=0.3, stray_m=1.5, leg_detour_m=0.0), positions=pos)
    off.set_goal(1, pos[0])
    assert off.update(pos[0]).via is None
    cells[:, 29:31] = OccupancyGrid.OCCUPIED
    sealed = SubgoalTracker(dataclasses.replace(m, grid=dataclasses.replace(grid, cells=cells)),
                            TrackerParams(reach_m=0.3, stray_m=1.5), positions=pos)
    sealed.set_goal(1, pos[0])
    st = sealed.update(pos[0])
    assert st.subgoal == 1 and st.via is None
    with pytest.raises(ValueError, match="leg_detour_m"):
        TrackerParams(leg_detour_m=-1.0)
