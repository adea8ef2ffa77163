"""Closed-loop simulator, incremental drift consistency, sequence source and CLI."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from litevloc.base.geometry import GeometryError, interpolate_pose_at, invert
from litevloc.base.params.drift import DriftParams
from litevloc.cli.main import main
from litevloc.hw.messages import GroundTruthPose, Odometry, RgbdFrame
from litevloc.hw.streams.mcap_io import McapSource
from litevloc.pipelines.odometry_drift import IncrementalDrift, resample_times, simulate_odometry
from litevloc.sim.elements import pose2d
from litevloc.sim.simulator import SimParams, Simulator
from litevloc.sim.source import SimSequenceSource
from litevloc.sim.world import load_world

TINY = SimParams(width=48, height=36)


@pytest.fixture(scope="module")
def office():
    return load_world("office")


def test_incremental_drift_matches_batch_model() -> None:
    times = np.arange(0, 3_000_000_000, 100_000_000, dtype=np.int64)
    poses = np.stack([pose2d(0.3 * k, 0.05 * k * k, 0.2 * k) for k in range(len(times))])
    params = DriftParams(yaw_bias_per_m=0.01)
    t_out, T_batch = simulate_odometry(times, poses, 50.0, params, seed=4)
    assert np.array_equal(t_out, resample_times(int(times[0]), int(times[-1]), 50.0))
    gt = np.stack([interpolate_pose_at(int(t), times, poses) for t in t_out])
    inc = IncrementalDrift(params, seed=4)
    out = [np.eye(4)]
    for k in range(1, len(t_out)):
        out.append(inc.step(invert(gt[k - 1]) @ gt[k], (t_out[k] - t_out[k - 1]) * 1e-9))
    assert np.allclose(np.stack(out), T_batch, atol=1e-12)
    # and it drifts: the end differs from the ground-truth motion
    assert np.linalg.norm(T_batch[-1][:3, 3] - (invert(gt[0]) @ gt[-1])[:3, 3]) > 1e-4


def test_closed_loop_rates_motion_and_collision(office) -> None:
    sim = Simulator(office, TINY, seed=1)
    c = office.room_centre(1)
    s0 = sim.reset(pose2d(c[0], c[1], 0.0))
    assert s0.frame is not None and s0.frame.color.shape == (36, 48, 3)
    assert s0.ground_truth.T_world_camera[2, 3] == pytest.approx(0.5, abs=0.02)
    frames, odoms = 0, 0
    for _ in range(50):  # 1 s at 0.3 m/s
        st = sim.step(0.3, 0.0, 0.02)
        frames += st.frame is not None
        odoms += len(st.odometry)
        assert not st.collided
    assert frames == 14 and odoms == 200  # + the reset frame: 15 frames in [0, 1] s
    assert st.T_world_base[0, 3] - c[0] == pytest.approx(0.3, abs=1e-6)
    assert st.t_ns == 1_000_000_000
    assert st.odometry[-1].T_odom_base[0, 3] == pytest.approx(0.3, abs=0.05)
    # drive into a wall: the robot stops before it and reports the collision
    collided = False
    for _ in range(200):
        st = sim.step(1.0, 0.0, 0.1)
        if st.collided:
            collided = True
            break
    assert collided
    assert office.is_free(st.T_world_base[:2, 3], TINY.robot_radius)
    with pytest.raises(GeometryError):
        sim.reset(pose2d(-5.0, -5.0, 0.0))
    with pytest.raises(ValueError):
        sim.step(0.1, 0.0, -1.0)


def test_sequence_source_is_ordered_and_deterministic(office) -> None:
    a = SimSequenceSource(office, "query", seed=3, duration=2.0, params=TINY)
    msgs = list(a)
    ts = [m.t_ns for m in msgs]
    assert ts == sorted(ts)
    frames = [m for m in msgs if isinstance(m, RgbdFrame)]
    assert len(frames) == a.frame_count() == 30
    assert sum(isinstance(m, GroundTruthPose) for m in msgs) == 30
    assert sum(isinstance(m, Odometry) for m in msgs) >= 400
    b = SimSequenceSource(office, "query", seed=3, duration=2.0, params=TINY)
    fb = [m for m in b if isinstance(m, RgbdFrame)]
    assert all(
        x.color.tobytes() == y.color.tobytes() and x.depth.tobytes() == y.depth.tobytes()
        for x, y in zip(frames, fb, strict=True)
    )
    c = SimSequenceSource(office, "query", seed=4, duration=2.0, params=TINY)
    assert c.frame(5).color.tobytes() != frames[5].color.tobytes()
    d = frames[10].depth
    assert d is not None and np.isnan(d).any() and np.isfinite(d).mean() > 0.5


def test_the_renderer_is_built_before_the_first_message_so_a_paced_replay_starts_on_time(office) -> None:
    """Building the renderer takes seconds in a large world: built at the first frame, a replay
    paced in real time would start its clock before it and hand the localizer stale frames."""
    e = SimSequenceSource(office, "query", seed=3, duration=2.0, params=TINY)
    assert e._renderer is None
    assert isinstance(next(iter(e)), Odometry) and e._renderer is not None


def test_frames_rendered_by_worker_processes_are_the_in_process_frames_in_order(office) -> None:
    from litevloc.runtime.tools.parallel_frames import rendered_frames

    e = SimSequenceSource(office, "query", seed=3, duration=1.0, params=TINY)
    here = [e.frame(i) for i in range(e.frame_count())]
    there = list(rendered_frames(e, workers=2))
    assert [f.index for f in there] == list(range(e.frame_count()))
    for a, b in zip(here, there, strict=True):
        assert np.array_equal(a.color, b.color) and a.t_ns == b.t_ns
        assert np.array_equal(a.depth, b.depth, equal_nan=True)
        assert b.color_jpeg is not None and b.color_jpeg[:2] == b"\xff\xd8"


def test_a_pass_refuses_frames_handed_to_it_out_of_order(office) -> None:
    e = SimSequenceSource(office, "query", seed=3, duration=1.0, params=TINY)
    frames = iter([e.frame(1), e.frame(0)])
    with pytest.raises(ValueError, match="frame 1 where frame 0 belongs"):
        list(e.messages(frames))


def test_cli_record_and_plot(tmp_path: Path) -> None:
    out = tmp_path / "seq.mcap"
    assert (
        main(
            [
                "sim",
                "record",
                "office",
                "-o",
                str(out),
                "--duration",
                "1",
                "--pass",
                "query",
                "--seed",
                "2",
                "--workers",
                "1",
                "--json",
                str(tmp_path / "s.json"),
                "--plot",
                str(tmp_path / "plan.png"),
            ]
        )
        == 0
    )
    again = tmp_path / "again.mcap"
    assert (
        main(
            [
                "sim",
                "record",
                "office",
                "-o",
                str(again),
                "--duration",
                "1",
                "--pass",
                "query",
                "--seed",
                "2",
                "--workers",
                "3",
            ]
        )
        == 0
    )
    # same seed -> byte-identical recording, whether rendered in this process or by three
    assert out.read_bytes() == again.read_bytes()
    assert json.loads((tmp_path / "s.json").read_text())["render_workers"] == 1
    msgs = list(McapSource(out))
    assert sum(isinstance(m, RgbdFrame) for m in msgs) == 15
    assert sum(isinstance(m, Odometry) for m in msgs) == 201
    assert (tmp_path / "plan.png").stat().st_size > 1000
    assert main(["sim", "record", "office", "-o", str(tmp_path / "x.txt")]) == 2
    assert main(["sim", "record", "office", "-o", str(tmp_path / "y.mcap"), "--workers", "0"]) == 2
    assert (
        main(
            [
                "sim",
                "goals",
                "office",
                "-o",
                str(tmp_path / "goals"),
                "--set",
                "sim.width=80",
                "--set",
                "sim.height=60",
            ]
        )
        == 0
    )
    import cv2

    img = cv2.imread(str(next((tmp_path / "goals").glob("room_*-hand.jpg"))))
    assert img is not None and img.shape == (60, 80, 3)
    goals = json.loads((tmp_path / "goals" / "goals.json").read_text())["goals"]
    assert {g["camera"] for g in goals.values()} == {"robot", "hand"} and len(goals) % 2 == 0


def test_open_sim_source_uri() -> None:
    from litevloc.sim.source import open_sim_source

    src = open_sim_source("sim:office?pass=query&seed=2&duration=0.5", TINY)
    assert src.pass_name == "query" and src.seed == 2 and src.frame_count() == 8
    for bad in (
        "office",
        "sim:",
        "sim:office?pass=nope",
        "sim:office?speed=2",
        "sim:office?seed=x",
    ):
        with pytest.raises(ValueError):
            open_sim_source(bad, TINY)


def test_depth_only_steps_render_no_colour_and_keep_the_frame_clock(office) -> None:
    start = sorted(office.goal_places.values(), key=lambda T: float(T[0, 3]))[0]
    a, b = Simulator(office, TINY, seed=3), Simulator(office, TINY, seed=3)
    a.reset(start)
    b.reset(start)
    for k in range(6):
        sa = a.step(0.2, 0.1, 0.2, color=True)
        sb = b.step(0.2, 0.1, 0.2, color=k % 3 == 0)
        assert sa.frame is not None and sa.depth is sa.frame.depth
        assert (sb.frame is None) == (k % 3 != 0) and sb.depth is not None and sb.depth.shape == (36, 48)
        np.testing.assert_array_equal(sa.T_world_base, sb.T_world_base)  # kinematics unaffected
        if sb.frame is not None:  # same frame index and noise seed as the all-colour run
            assert sb.frame.index == sa.frame.index
            np.testing.assert_array_equal(sb.frame.color, sa.frame.color)


def test_map_pass_enters_every_room_and_corridor_and_looks_around() -> None:
    """The operator-like mapping pass: a full turn in every room and along the corridor, and in
    every room sweeps into it from spots in its outer part, driven without touching anything.
    In this building the first follower cut a door's corner, pushed against the jamb and never
    entered three of the six rooms."""
    from litevloc.sim.simulator import SimParams
    from litevloc.sim.trajectory import EDGE_SWEEP_RAD, follow, pass_tasks

    world = load_world("office-aliased", seed=2)
    params = SimParams(odometry_rate_hz=50.0)  # the follower's ticks: 4x fewer than the default, as tight
    start, tasks = pass_tasks(world, "map", 0, params)
    spots, here = [], start[:2, 3]
    for t in tasks:  # where each look happens: full turns, and sweeps (face, then turn 2 x sweep)
        if t.kind == "goto":
            here = t.path[-1]
        elif t.kind == "turn":
            spots.append((world.region_at(here), "full" if abs(abs(t.angle) - 2 * np.pi) < 1e-9 else "sweep"))
            assert abs(abs(t.angle) - 2 * np.pi) < 1e-9 or abs(t.angle - 2 * EDGE_SWEEP_RAD) < 1e-9
    rooms = {k for k, r in world.regions.items() if r.kind == "room"}
    corridor = next(k for k, r in world.regions.items() if r.kind == "corridor")
    assert {k for k, how in spots if how == "full"} == set(world.regions)  # every room and the corridor
    assert all(sum(s == (k, "sweep") for s in spots) == 3 for k in rooms)  # three sweeps into every room
    assert sum(s == (corridor, "full") for s in spots) >= 2  # the corridor's ends, 8 m apart at most
    run = follow(world, params, 0, start, tasks)
    assert run.collisions == 0
    assert {world.region_at(p) for p in run.T_world_base[::20, :2, 3]} == set(world.regions)
    _, side = pass_tasks(world, "map-rooms", 0, params)  # three full turns in every room, none in corridors
    assert sum(t.kind == "turn" for t in side) == 3 * len(rooms)
