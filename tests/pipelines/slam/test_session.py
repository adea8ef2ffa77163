"""The SLAM core on a synthetic robot (tests/pipelines/slam/synthetic.py): loops close, drift
goes, and each fault of a mapping recording is bridged or reported, never a bent map."""

from __future__ import annotations

import dataclasses
import itertools
from typing import Any

import numpy as np
import pytest

from litevloc.base.geometry import invert, make_T
from litevloc.config import load_config
from litevloc.pipelines.slam.graph import optimise
from litevloc.pipelines.slam.planes import resolve_with_walls
from litevloc.pipelines.slam.types import Edge
from tests.pipelines.slam.synthetic import Scene, keyframe_ate, keyframe_ate_of, make_scene, run_session


@pytest.fixture(scope="module")
def scene() -> Scene:
    return make_scene(240, 1.2)


@pytest.fixture(scope="module")
def base(scene: Scene):  # type: ignore[no-untyped-def]
    return run_session(scene)


def test_loops_remove_the_odometry_drift(scene: Scene, base) -> None:  # type: ignore[no-untyped-def]
    session, res = base
    rep = res.report
    assert rep["loops"]["verified"] >= 3 and rep["loops"]["kept"] == rep["loops"]["verified"]
    assert rep["faults"] == [] and rep["chains"] == 1 and rep["keyframes_in_map"] == rep["keyframes"]
    odo = session.odometry_poses(res)
    assert odo is not None
    ids = sorted(odo)
    from litevloc.pipelines.evaluation.trajectory import ate

    odo_ate = ate(np.stack([odo[i] for i in ids]), np.stack([scene.T_world_camera(res.keyframes[i].index)
                                                              for i in ids])).rmse
    assert odo_ate > 0.1  # the odometry really drifts (2 deg/m yaw bias)
    assert keyframe_ate(scene, res) < 0.005
    # every frame is posed, and the keyframes' frames carry their keyframe pose
    assert all(T is not None for T in res.frame_poses)
    for rec, T in zip(res.frames, res.frame_poses, strict=True):
        if rec.keyframe is not None:
            assert np.allclose(T, res.graph.poses[rec.keyframe])


def test_keyframes_know_their_path_along_the_chain(scene: Scene, base) -> None:  # type: ignore[no-untyped-def]
    # the loop search's chain pre-gate bounds a loop by the path between its keyframes
    _, res = base
    kfs = res.keyframes
    true = [scene.T_world_camera(k.index)[:3, 3] for k in kfs]
    length = sum(float(np.linalg.norm(b - a)) for a, b in itertools.pairwise(true))
    assert abs(kfs[-1].path_m - length) < 0.02 * length
    assert all(b.path_m >= a.path_m and b.path_var_t > a.path_var_t for a, b in itertools.pairwise(kfs))


def test_saved_graph_reoptimises_to_the_same_map(base, tmp_path) -> None:  # type: ignore[no-untyped-def]
    # the simulator's preset holds the base on one level floor: the saved graph keeps that too
    from litevloc.runtime.tools.slam_build import load_graph, save_graph, solve_saved

    _, res = base
    assert res.level is not None
    save_graph(tmp_path / "g.npz", res)
    g = load_graph(tmp_path / "g.npz")
    assert g.level is not None and abs(g.level.height_m - res.level.height_m) < 1e-12
    again = solve_saved(g, load_config("default").slam)
    assert max(float(np.abs(again.poses[i] - T).max()) for i, T in res.graph.poses.items()) < 1e-6


def test_map_frame_is_the_first_keyframe_levelled(base) -> None:  # type: ignore[no-untyped-def]
    _, res = base
    from tests.pipelines.slam.synthetic import T_BASE_CAMERA

    T0 = res.graph.poses[0] @ invert(T_BASE_CAMERA)  # base_link of the first keyframe in the map
    assert np.allclose(T0[:3, 3], 0.0, atol=1e-6)
    assert abs(T0[2, 2] - 1.0) < 1e-3  # odometry z is up


def test_wrong_loops_cannot_bend_the_map(scene: Scene, base) -> None:  # type: ignore[no-untyped-def]
    _, res = base
    cfg = load_config("default")
    kfs = res.keyframes
    P = res.graph.poses
    rng = np.random.default_rng(1)
    wrong: list[Edge] = []
    while len(wrong) < max(2, round(0.3 * len(res.loops))):  # 30 % of the loops again, all wrong
        a, b = sorted(rng.choice(len(kfs), 2, replace=False).tolist())
        if np.linalg.norm(P[a][:3, 3] - P[b][:3, 3]) > 2.5:  # claim they are 10 cm apart
            wrong.append(Edge(a, b, make_T(np.eye(3), np.array([0.1, 0.0, 0.0])), res.loops[0].covariance, "loop"))
    g = optimise(kfs, res.edges + wrong, res.T_map_first, cfg.slam.graph, res.level)
    assert res.walls is not None and res.walls.factors.count > 0  # the scene's walls are in the final solve
    g = resolve_with_walls(kfs, res.edges + wrong, g, res.T_map_first, cfg.slam.graph, cfg.slam.planes,
                           res.walls.factors, res.level)
    moved = max(np.linalg.norm(g.poses[i][:3, 3] - P[i][:3, 3]) for i in P)
    assert moved < 1e-4  # the kept loops are the same: the same least-squares solution
    n = len(res.loops)
    assert all(w < 0.5 for w in g.loop_weights[n:]) and all(w > 0.5 for w in g.loop_weights[:n])
    # without the robust loss the same loops do bend it: the test can fail
    plain = optimise(kfs, [e if e.kind != "loop" else Edge(e.a, e.b, e.T_a_b, e.covariance, "visual")
                           for e in res.edges + wrong], res.T_map_first, cfg.slam.graph, res.level)
    assert max(np.linalg.norm(plain.poses[i][:3, 3] - P[i][:3, 3]) for i in P) > 0.1


def test_odometry_gap_is_bridged_by_visual_odometry(scene: Scene) -> None:
    _, res = run_session(scene, drop_odometry_s=(5.0, 10.0))
    rep = res.report
    assert [f["kind"] for f in rep["faults"]] == ["odometry gap"]
    assert rep["frames_tracked"] > 20 and rep["chains"] == 1 and rep["keyframes_left_out"] == 0
    assert keyframe_ate(scene, res) < 0.005


def test_camera_blackout_is_bridged_by_odometry(scene: Scene) -> None:
    # this scene's visual edges err as their covariance says (no refinement bias to correct), so the
    # visual covariance is not inflated here: the test is about the bridge, the bound about the scene
    cfg = load_config("default")
    cfg = dataclasses.replace(cfg, slam=dataclasses.replace(
        cfg.slam, graph=dataclasses.replace(cfg.slam.graph, visual_covariance_scale=1.0)))
    _, res = run_session(scene, cfg=cfg, drop_frames_s=(5.0, 10.0))
    rep = res.report
    assert rep["chains"] == 1 and rep["keyframes_left_out"] == 0 and rep["loops"]["kept"] > 0
    t = [kf.t_ns * 1e-9 for kf in res.keyframes]
    assert not any(5.0 <= x < 10.0 for x in t)
    assert keyframe_ate(scene, res) < 0.005


def test_odometry_jump_is_cut_out(scene: Scene) -> None:
    _, res = run_session(scene, odometry_shift=lambda t: 2.0 if t > 7.0 else 0.0)
    rep = res.report
    assert [f["kind"] for f in rep["faults"]] == ["odometry jump"]
    assert "2.0" in rep["faults"][0]["detail"] or "1.9" in rep["faults"][0]["detail"]
    assert rep["keyframes_left_out"] == 0 and keyframe_ate(scene, res) < 0.005


def test_one_aliased_image_does_not_outvote_the_odometry() -> None:
    # the frames around 7 s look as if taken 15 cm further along the optical axis (a texture that
    # repeats down a corridor): both visual edges into that keyframe shift alike; the odometry is right
    scene = make_scene(240, 1.2)
    scene.aliased = {i: np.array([0.0, 0.0, 0.15]) for i, t in enumerate(scene.t_ns) if 7.0 <= t * 1e-9 < 7.4}
    _, res = run_session(scene)
    rep = res.report
    assert rep["edges"]["odometry_dropped"] == 0
    assert [f["kind"] for f in rep["faults"]] == ["vision disagrees with odometry"]
    assert keyframe_ate(scene, res) < 0.005


def _skip_edge_ties() -> Any:
    cfg = load_config("default")
    return dataclasses.replace(cfg, slam=dataclasses.replace(
        cfg.slam, visual=dataclasses.replace(cfg.slam.visual, skip_edge_ties=True)))


def test_slow_odometry_slip_is_reported(scene: Scene) -> None:
    # 0.5 m of extra motion over one second: slower than the jump check; one image is one vote, so
    # the visual edges cannot overrule the odometry, and the disagreement is reported where it happened
    _, res = run_session(scene, odometry_shift=lambda t: 0.5 * min(max(t - 7.0, 0.0), 1.0))
    rep = res.report
    assert [f["kind"] for f in rep["faults"]] == ["vision disagrees with odometry"]
    assert 7.0 <= rep["faults"][0]["t_s"] <= 8.0


def test_slow_odometry_slip_is_corrected_by_the_skip_edge(scene: Scene) -> None:
    # the same slip with slam.visual.skip_edge_ties: the next keyframe seen from the one before the
    # tie (a second image) sides with vision: the slipped odometry edges are dropped where it happened
    _, res = run_session(scene, _skip_edge_ties(), odometry_shift=lambda t: 0.5 * min(max(t - 7.0, 0.0), 1.0))
    rep = res.report
    assert [f["kind"] for f in rep["faults"]] == ["odometry disagrees with vision"]
    assert 7.0 <= rep["faults"][0]["t_s"] <= 8.0 and rep["edges"]["odometry_dropped"] >= 1
    assert rep["chains"] == 1 and keyframe_ate(scene, res) < 0.005


def test_one_aliased_image_does_not_win_the_skip_edge_vote() -> None:
    scene = make_scene(240, 1.2)
    scene.aliased = {i: np.array([0.0, 0.0, 0.15]) for i, t in enumerate(scene.t_ns) if 7.0 <= t * 1e-9 < 7.4}
    _, res = run_session(scene, _skip_edge_ties())
    rep = res.report
    assert rep["edges"]["odometry_dropped"] == 0
    assert [f["kind"] for f in rep["faults"]] == ["vision disagrees with odometry"]
    assert keyframe_ate(scene, res) < 0.005


def test_jump_in_a_blackout_splits_the_chain_and_a_loop_joins_it(scene: Scene) -> None:
    # neither odometry nor vision links across: a new chain, which the second lap's loops join
    _, res = run_session(scene, odometry_shift=lambda t: 2.0 if t > 7.0 else 0.0, drop_frames_s=(6.0, 9.0))
    rep = res.report
    assert rep["chains"] == 2
    kinds = [f["kind"] for f in rep["faults"]]
    assert "odometry jump" in kinds and "keyframe not linked" in kinds
    assert rep["keyframes_left_out"] == 0 and keyframe_ate(scene, res) < 0.01


def test_a_chain_no_loop_joins_is_left_out(scene: Scene) -> None:
    # the same split on a shorter drive: no revisit after the split, so the second chain is dropped
    short = make_scene(150, 0.75)
    _, res = run_session(short, odometry_shift=lambda t: 2.0 if t > 5.0 else 0.0, drop_frames_s=(4.0, 7.0))
    rep = res.report
    assert rep["chains"] == 2 and rep["keyframes_left_out"] > 0
    assert any("left out" in w for w in rep["warnings"])
    left = set(res.graph.dropped)
    assert all(res.keyframes[i].t_ns * 1e-9 >= 7.0 for i in left)
    posed = [r for r, T in zip(res.frames, res.frame_poses, strict=True) if T is not None]
    assert posed and all(r.t_ns * 1e-9 < 7.0 for r in posed)


def test_camera_only_is_visual_odometry(scene: Scene) -> None:
    _, res = run_session(scene, odometry=False)
    rep = res.report
    assert rep["odometry_source"].startswith("none") and rep["edges"]["odometry"] == 0
    assert any("no odometry" in w for w in rep["warnings"])
    assert "camera mount" in rep["up"]
    assert keyframe_ate(scene, res) < 0.005


def test_walls_only_where_the_up_is_measured(scene: Scene) -> None:
    # no odometry and no planar robot: the map's up is the camera mount's guess, walls cannot be told
    cfg = load_config("default")
    cfg = dataclasses.replace(cfg, slam=dataclasses.replace(
        cfg.slam, planar=dataclasses.replace(cfg.slam.planar, enabled=False, level_floor=False)))
    _, res = run_session(scene, cfg, odometry=False)
    assert res.walls is None and res.report["walls"].startswith("off: the map's up")
    _, res = run_session(scene, odometry=False)  # the same camera on a ground robot (slam.planar)
    assert res.walls is not None and res.walls.factors.count > 0


def _shifted_loops(scene: Scene, res, pairs: list[tuple[int, int]], shift_m: float) -> list[Edge]:  # type: ignore[no-untyped-def]
    """Loops as a repeating corridor verifies them: keyframe b seen as if `shift_m` (world x)
    from where it is, the same shift for all (consistent among themselves, not with the chain)."""
    G = {i: scene.T_world_camera(res.keyframes[i].index) for i in range(len(res.keyframes))}
    S = make_T(np.eye(3), np.array([shift_m, 0.0, 0.0]))
    cov = res.loops[0].covariance
    return [Edge(a, b, invert(G[a]) @ S @ G[b], cov, "loop") for a, b in pairs]


def test_a_repetition_the_chain_contradicts_is_rejected(scene: Scene, base) -> None:  # type: ignore[no-untyped-def]
    # twice as many loops shifted by 1 m as true ones, between keyframes 8-12 apart: the chain
    # (a few metres, mm-accurate) says they are 1 m off, so the gate rejects them all
    _, res = base
    cfg = load_config("default")
    n = len(res.loops)
    pairs = [(a, a + d) for a in range(len(res.keyframes)) for d in (8, 10, 12) if a + d < len(res.keyframes)]
    wrong = _shifted_loops(scene, res, pairs[: 2 * n], 1.0)
    assert len(wrong) == 2 * n
    g = optimise(res.keyframes, res.edges + wrong, res.T_map_first, cfg.slam.graph, res.level)
    assert g.loop_gate[:n] == [""] * n and all(w > 0.5 for w in g.loop_weights[:n])
    assert g.loop_gate[n:] == ["chain gate"] * len(wrong) and all(w == 0.0 for w in g.loop_weights[n:])
    assert keyframe_ate_of(scene, res, g.poses) < 0.005
    # kept, these loops would bend the map (plain least squares over all of them)
    plain = optimise(res.keyframes, [e if e.kind != "loop" else Edge(e.a, e.b, e.T_a_b, e.covariance, "visual")
                                     for e in res.edges + wrong], res.T_map_first, cfg.slam.graph, res.level)
    assert keyframe_ate_of(scene, res, plain.poses) > 0.05


def test_a_repetition_at_the_revisit_loses_to_the_true_loops(scene: Scene, base) -> None:  # type: ignore[no-untyped-def]
    # loops shifted by 0.4 m where the lap closes: within the chain's drift over the lap, so the
    # chain gate lets them by, but they do not close cycles with the true loops (PCM)
    _, res = base
    cfg = load_config("default")
    n = len(res.loops)
    wrong = _shifted_loops(scene, res, [(e.a, e.b) for e in res.loops[: n // 2]], 0.4)
    g = optimise(res.keyframes, res.edges + wrong, res.T_map_first, cfg.slam.graph, res.level)
    assert g.loop_gate[:n] == [""] * n
    assert g.loop_gate[n:] == ["pairwise consistency"] * len(wrong)
    assert keyframe_ate_of(scene, res, g.poses) < 0.005


def test_only_loop_search_keyframes_search_and_are_found(base) -> None:  # type: ignore[no-untyped-def]
    # the loop search runs on every slam.loops.search_every-th keyframe only, among such keyframes
    session, res = base
    n = load_config("default").slam.loops.search_every
    assert n > 1
    assert res.loops and all(e.a % n == 0 and e.b % n == 0 for e in res.loops)
    assert {a.query for a in session.attempts} <= {kf.id for kf in res.keyframes if kf.id % n == 0}


def _keyframes(scene: Scene, params: Any, n: int = 60) -> list[Any]:
    """The front end's keyframes over the scene's first `n` frames with exact odometry."""
    from litevloc.pipelines.slam.frontend import FrontEnd
    from tests.pipelines.slam.synthetic import T_BASE_CAMERA

    cfg = load_config("default")
    front = FrontEnd(params, cfg.mapping, cfg.localization, scene.models(), T_BASE_CAMERA)
    for i in range(n):
        front.add(scene.frame_ref(i), (0, scene.T_world_base[i]))
    return front.keyframes


def test_sparser_keyframe_spacing_makes_fewer_keyframes(scene: Scene) -> None:
    from litevloc.base.geometry import rotation_angle

    cfg = load_config("default")
    sparse = dataclasses.replace(cfg.slam, keyframe_step_scale=2.0)
    kp = cfg.mapping.keyframes
    counts = []
    for params in (cfg.slam, sparse):
        keyframes = _keyframes(scene, params)
        counts.append(len(keyframes))
        for a, b in itertools.pairwise(keyframes):  # the frame before b had not moved a step from a
            Ta, Tb = scene.T_world_camera(a.index), scene.T_world_camera(b.index - 1)
            k, k_rot = params.keyframe_step_scale, params.keyframe_step_scale * params.keyframe_rotation_scale
            assert np.linalg.norm(Tb[:3, 3] - Ta[:3, 3]) < k * kp.min_translation_m
            assert np.degrees(rotation_angle(Ta[:3, :3].T @ Tb[:3, :3])) < k_rot * kp.min_rotation_deg
    assert counts[1] < 0.7 * counts[0]


def test_a_larger_rotation_step_spaces_only_turning_keyframes(scene: Scene) -> None:
    # slam.keyframe_rotation_scale: a robot turning on the spot makes fewer keyframes, driving ones are as before
    cfg = load_config("default")
    same, turns = (dataclasses.replace(cfg.slam, keyframe_rotation_scale=k) for k in (1.0, 2.0))
    spinning = make_scene(n_frames=40, laps=0.4, radius=0.15)  # 0.3 m of arc is ~115 deg: turns make keyframes
    n_spin = [len(_keyframes(spinning, p, 40)) for p in (same, turns)]
    assert n_spin[1] < 0.7 * n_spin[0]
    driving = [[kf.index for kf in _keyframes(scene, p, 40)] for p in (same, turns)]
    assert driving[0] == driving[1] and len(driving[0]) > 3  # on the 1.8 m circle 0.3 m come before 12 deg
