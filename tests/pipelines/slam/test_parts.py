"""The SLAM's small parts: odometry segments, edge noise, the map frame, frame poses, trajectories."""

from __future__ import annotations

import numpy as np

from litevloc.base.geometry import invert, make_T, so3_exp
from litevloc.base.params.slam import SlamOdometryParams
from litevloc.pipelines.slam.frames import frame_poses, interpolate_trajectory
from litevloc.pipelines.slam.odometry import OdometryTrack, odometry_edge
from litevloc.pipelines.slam.session import map_frame, up_rotation
from litevloc.pipelines.slam.types import FrameRecord


def _pose(x: float, yaw: float = 0.0) -> np.ndarray:
    return make_T(so3_exp(np.array([0.0, 0.0, yaw])), np.array([x, 0.0, 0.0]))


def test_odometry_track_splits_at_gaps_and_jumps() -> None:
    tr = OdometryTrack(SlamOdometryParams(max_gap_s=0.5, max_speed_mps=5.0))
    for k in range(10):  # 1 m/s, 100 Hz
        tr.add(k * 10_000_000, _pose(0.01 * k))
    tr.add(100_000_000, _pose(2.1))  # 2 m in 10 ms: a jump
    tr.add(110_000_000, _pose(2.11))
    tr.add(2_000_000_000, _pose(3.0))  # 1.9 s of silence: a gap
    tr.add(1_000_000_000, _pose(9.0))  # backwards in time: dropped
    assert tr.segments == 3 and tr.out_of_order == 1
    assert [f.kind for f in tr.faults] == ["odometry jump", "odometry gap"]
    s, T = tr.pose_at(45_000_000)  # type: ignore[misc]
    assert s == 0 and abs(T[0, 3] - 0.045) < 1e-9
    assert tr.pose_at(95_000_000) is None  # across the jump: no segment covers it
    assert tr.pose_at(500_000_000) is None  # inside the gap
    assert tr.pose_at(110_000_000)[0] == 1  # type: ignore[index]


def test_odometry_edge_noise_grows_with_motion_and_turns_into_the_camera_frame() -> None:
    p = SlamOdometryParams(sigma_m_per_m=0.02, sigma_floor_m=0.001, sigma_deg_per_m=1.0, sigma_deg_per_deg=0.01,
                           sigma_floor_deg=0.1)
    T_bc = make_T(np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]), np.array([0.3, 0.0, 0.5]))
    a, b = _pose(0.0), _pose(1.0, 0.2)
    T, cov = odometry_edge(a, b, T_bc, p)
    assert np.allclose(T, invert(a @ T_bc) @ b @ T_bc)
    _, cov_short = odometry_edge(a, _pose(0.1), T_bc, p)
    assert np.trace(cov[3:, 3:]) > 10 * np.trace(cov_short[3:, 3:])
    # no lever arm: the camera-frame noise is the base's (isotropic per axis), no rotation-translation terms;
    # with the lever arm, rotation noise of the base moves the camera: translation noise grows
    _, c0 = odometry_edge(a, b, make_T(T_bc[:3, :3], np.zeros(3)), p)
    s_t = np.hypot(0.02 * np.linalg.norm(b[:3, 3]), 0.001)
    assert np.allclose(np.diag(c0)[3:], s_t**2) and np.allclose(c0[3:, :3], 0)
    assert np.all(np.diag(cov)[3:] >= s_t**2 - 1e-15) and np.diag(cov)[3:].max() > 1.01 * s_t**2


def test_map_frame_is_levelled_and_turned_to_up() -> None:
    T_bc = make_T(np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]), np.zeros(3))
    tilted = make_T(so3_exp(np.array([0.02, -0.03, 1.0])), np.array([5.0, 2.0, 0.1]))
    T, note = map_frame(tilted, T_bc, (0.0, 0.0, 1.0))
    base = T @ invert(T_bc)
    assert np.allclose(base[:3, 3], 0.0) and "odometry" in note
    # the base keeps its tilt relative to the level odometry frame, its heading is the map's x
    assert abs(base[2, 2] - tilted[2, 2]) < 1e-9 and abs(base[1, 0]) < 0.05
    up = (0.0, -0.9, -0.43)
    R = up_rotation(up)
    assert np.allclose(R @ [0, 0, 1], np.asarray(up) / np.linalg.norm(up))
    T2, note2 = map_frame(None, T_bc, up)
    assert "camera mount" in note2 and np.allclose(T2[:3, :3], R @ T_bc[:3, :3])


def test_frame_poses_meet_both_keyframes() -> None:
    # keyframes 0 (t=0) and 1 (t=10): the increments say 1 m, the optimiser says 1.1 m
    recs = [FrameRecord(0, 0, keyframe=0), FrameRecord(1, 5, anchor=0, T_anchor_frame=_pose(0.5), how="odometry"),
            FrameRecord(2, 10, anchor=0, T_anchor_frame=_pose(1.0), how="odometry", keyframe=1),
            FrameRecord(3, 12), FrameRecord(4, 14, anchor=1, T_anchor_frame=_pose(0.2), how="visual", keyframe=2)]
    poses = {0: _pose(0.0), 1: _pose(1.1), 2: _pose(1.3)}
    out = frame_poses(recs, poses)
    assert np.allclose(out[0], poses[0]) and np.allclose(out[2], poses[1]) and np.allclose(out[4], poses[2])
    assert abs(out[1][0, 3] - 0.55) < 1e-9  # half-way: the 0.1 m discrepancy spread by time
    assert abs(out[3][0, 3] - 1.2) < 1e-9  # no relation: interpolated between its neighbours
    assert frame_poses(recs, {0: _pose(0.0)})[2] is None  # keyframe 1 left out of the map


def test_interpolate_trajectory_skips_outside_and_gaps() -> None:
    t = np.array([0, 100, 200, 1_000], np.int64)
    P = np.stack([_pose(0.0), _pose(1.0), _pose(2.0), _pose(3.0)])
    out = interpolate_trajectory(t, P, [-1, 50, 200, 500, 1_001], max_gap_ns=150)
    assert out[0] is None and out[3] is None and out[4] is None
    assert abs(out[1][0, 3] - 0.5) < 1e-12 and np.allclose(out[2], P[2])  # type: ignore[index]
