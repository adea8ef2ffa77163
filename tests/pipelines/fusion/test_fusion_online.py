"""OnlineFusion: outlier robustness, late VLoc at capture time, no dropped odometry, bounds."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import numpy as np
import pytest

from litevloc.base.geometry import (
    gtsam_to_ros_covariance,
    interpolate_pose_at,
    make_T,
    ros_to_gtsam_covariance,
    so3_exp,
)
from litevloc.base.params.drift import T_BASE_CAMERA_OPTICAL, DriftParams
from litevloc.base.params.fusion import FusionParams
from litevloc.experiments.fusion_sim import run_online, simulate_vloc, synthetic_trajectory
from litevloc.pipelines.evaluation.trajectory import ate
from litevloc.pipelines.fusion.online import OnlineFusion
from litevloc.pipelines.odometry_drift import simulate_odometry

T_BC = T_BASE_CAMERA_OPTICAL


@pytest.fixture(scope="module")
def session() -> dict:
    """90 s synthetic session: GT at 30 Hz, drift odometry at 100 Hz (seed 0)."""
    gt_t, T_wb = synthetic_trajectory(90.0, 30.0, seed=2)
    ot, oT = simulate_odometry(gt_t, T_wb, 100.0, DriftParams(), seed=0)
    gt_o = np.stack([interpolate_pose_at(int(t), gt_t, T_wb) for t in ot])
    return {"gt_t": gt_t, "T_wb": T_wb, "ot": ot, "oT": oT, "gt_o": gt_o}


def _fused_ate(s: dict, params: FusionParams, outliers: float, seed: int = 7) -> float:
    vl = simulate_vloc(
        s["gt_t"],
        s["T_wb"] @ T_BC,
        1.0,
        params.vloc_sigma_trans,
        params.vloc_sigma_rot_deg,
        outliers,
        seed=seed,
    )
    run = run_online(params, T_BC, s["ot"], s["oT"], vl)
    m = run.initialised
    assert m.sum() > 0.9 * len(m)
    return ate(run.T_map_base[m], s["gt_o"][m], align=False).rmse


def test_outliers_do_not_hurt_with_robust_kernel_and_gating(session: dict) -> None:
    p = FusionParams()
    clean = _fused_ate(session, p, 0.0)
    dirty = _fused_ate(session, p, 0.1)
    naive = _fused_ate(session, dataclasses.replace(p, robust_kernel="none", gate_chi2=0.0), 0.1)
    assert dirty <= 1.5 * clean, (clean, dirty)
    assert naive >= 2.0 * dirty, (dirty, naive)  # without kernel and gate, outliers pull it off


def _straight_line_run(capture_delay_ns: int, stamp_at_arrival: bool) -> np.ndarray:
    """1 m/s along x; odometry over-reads by 10 %; exact VLoc every 1 s, arriving late."""
    p = FusionParams(
        vloc_sigma_trans=0.005,
        vloc_sigma_rot_deg=0.2,
        gate_chi2=0.0,
        robust_kernel="none",
        init_votes=1,
    )
    f = OnlineFusion(p, np.eye(4))
    t_ns = np.arange(0, 8_000_000_001, 10_000_000, dtype=np.int64)  # 100 Hz, 8 s
    vloc_capture = [int(0.5e9) + k * int(1e9) for k in range(7)]
    pending = [(c + capture_delay_ns, c) for c in vloc_capture]
    out = None
    for t in t_ns:
        while pending and pending[0][0] <= t:
            arrival, capture = pending.pop(0)
            truth = make_T(np.eye(3), [capture * 1e-9, 0.0, 0.0])
            res = f.add_vloc(arrival if stamp_at_arrival else capture, truth)
            assert res.accepted, res
        T_odom = make_T(np.eye(3), [1.1 * t * 1e-9, 0.0, 0.0])
        fused = f.add_odometry(int(t), T_odom)
        if fused is not None:
            out = fused.T_map_base
    assert out is not None
    return out


def test_late_vloc_is_applied_at_its_capture_time() -> None:
    on_time = _straight_line_run(0, stamp_at_arrival=False)
    late = _straight_line_run(800_000_000, stamp_at_arrival=False)
    wrong = _straight_line_run(800_000_000, stamp_at_arrival=True)  # what a naive filter does
    truth_x = 8.0
    # The last VLoc was captured at 6.5 s: 1.5 s of 10 % over-reading odometry since.
    assert abs(late[0, 3] - on_time[0, 3]) < 0.01
    assert abs(late[0, 3] - (truth_x + 0.15)) < 0.03
    assert abs(wrong[0, 3] - truth_x) > 0.5  # treating capture as arrival time is 0.8 m off


def test_no_odometry_message_is_dropped_and_bad_input_is_counted(session: dict) -> None:
    s = session
    p = FusionParams()
    f = OnlineFusion(p, T_BC)
    vl = simulate_vloc(s["gt_t"], s["T_wb"] @ T_BC, 1.0, outlier_ratio=0.1, seed=3)
    order = np.argsort(vl.t_arrival_ns)
    j = 0
    outputs = after_init = 0
    n = 3000
    for i in range(n):
        t = int(s["ot"][i])
        while j < len(order) and vl.t_arrival_ns[order[j]] <= t:
            k = order[j]
            f.add_vloc(int(vl.t_capture_ns[k]), vl.T_map_camera[k])
            f.add_vloc(
                int(vl.t_capture_ns[k]), np.full((4, 4), np.nan)
            )  # junk VLoc between messages
            j += 1
        was_init = f.initialised
        out = f.add_odometry(t, s["oT"][i])
        if f.initialised:
            after_init += 1
            assert out is not None and out.t_ns == t and out.initialised
            assert out.covariance.shape == (6, 6)
            assert np.all(np.linalg.eigvalsh(out.covariance) > 0)
            np.testing.assert_allclose(out.T_map_odom @ s["oT"][i], out.T_map_base, atol=1e-9)
            outputs += 1
        else:
            assert out is None and not was_init
    assert outputs == after_init > 0.9 * n
    bad = np.eye(4)
    bad[0, 0] = np.nan
    assert f.add_odometry(int(s["ot"][n]), bad) is None
    assert f.add_odometry(int(s["ot"][n - 5]), s["oT"][n - 5]) is None  # time going backwards
    st = f.stats()
    assert st["odometry_rejected"] == {"invalid_pose": 1, "time_not_increasing": 1}
    assert st["fused_outputs"] == outputs
    assert st["vloc_by_reason"]["invalid_pose"] == j
    assert st["vloc_by_reason"].get("gated", 0) >= 1


def test_state_count_is_bounded(session: dict) -> None:
    s = session
    p = FusionParams()
    counts: list[int] = []

    def probe(i: int, fusion: OnlineFusion) -> None:
        if i % 500 == 0 and fusion.initialised:
            counts.append(fusion.states_in_graph())

    vl = simulate_vloc(s["gt_t"], s["T_wb"] @ T_BC, 1.0, outlier_ratio=0.1, seed=4)
    run = run_online(p, T_BC, s["ot"], s["oT"], vl, on_sample=probe)
    bound = p.lag_s / p.keyframe_period_s + 10
    assert max(counts) <= bound
    assert run.stats["keyframes"] > 5 * bound  # many more states were created than kept
    assert run.stats["covariance_computations"] <= 90 / p.covariance_period_s + 2  # not per update


def test_first_vloc_outlier_does_not_seed_the_filter() -> None:
    f = OnlineFusion(FusionParams(init_votes=2), np.eye(4))
    for k in range(50):
        f.add_odometry(k * 10_000_000, np.eye(4))
    assert (
        f.add_vloc(100_000_000, make_T(so3_exp(np.array([0, 0, 1.0])), [3.0, 1.0, 0.0])).reason
        == "awaiting_init"
    )
    assert f.add_vloc(200_000_000, np.eye(4)).reason == "awaiting_init"  # disagrees with the first
    r = f.add_vloc(300_000_000, make_T(np.eye(3), [0.01, 0, 0]))
    assert r.accepted and r.reason == "initialised"
    out = f.add_odometry(500_000_000, np.eye(4))
    assert out is not None and np.linalg.norm(out.T_map_base[:3, 3]) < 0.05


def test_vloc_older_than_window_is_rejected_not_misapplied() -> None:
    p = FusionParams(init_votes=1, lag_s=1.0, odom_buffer_s=1.0)
    f = OnlineFusion(p, np.eye(4))
    f.add_odometry(0, np.eye(4))
    assert f.add_vloc(0, np.eye(4)).reason == "initialised"
    for k in range(1, 301):
        f.add_odometry(k * 10_000_000, np.eye(4))
    assert f.add_vloc(500_000_000, np.eye(4)).reason == "too_old"
    assert f.add_vloc(3_500_000_000, np.eye(4)).reason == "ahead_of_odometry"
    assert f.add_vloc(2_900_000_000, np.eye(4)).reason == "accepted"


def test_params_and_covariance_order() -> None:
    with pytest.raises(ValueError, match="robust_kernel"):
        FusionParams(robust_kernel="tukey")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="lag_s"):
        FusionParams(lag_s=0.1, keyframe_period_s=0.1)
    C = np.diag([1.0, 2, 3, 4, 5, 6])  # ROS: x y z rx ry rz
    np.testing.assert_array_equal(np.diag(ros_to_gtsam_covariance(C)), [4, 5, 6, 1, 2, 3])
    np.testing.assert_array_equal(gtsam_to_ros_covariance(ros_to_gtsam_covariance(C)), C)
    with pytest.raises(ValueError, match="T_base_camera"):
        OnlineFusion(FusionParams(), np.zeros((4, 4)))


def test_solver_error_is_counted_and_the_filter_restarts() -> None:
    f = OnlineFusion(FusionParams(init_votes=1), np.eye(4))
    f.add_odometry(0, np.eye(4))
    assert f.add_vloc(0, np.eye(4)).accepted

    class Broken:
        def update(self, *args: object) -> None:
            raise RuntimeError("Indeterminant linear system")

    f._w.smoother = Broken()  # type: ignore[assignment]
    assert f.add_odometry(200_000_000, np.eye(4)) is None  # the keyframe update failed
    st = f.stats()
    assert st["solver_errors"] == 1 and not f.initialised
    assert f.add_vloc(200_000_000, np.eye(4)).reason == "initialised"  # recovers from the next VLoc
    assert f.add_odometry(300_000_000, np.eye(4)) is not None


def test_votes_only_initialise_and_are_ignored_afterwards() -> None:
    """Provisional (single-keyframe) GL poses count towards initialisation, never after it."""
    f = OnlineFusion(FusionParams(init_votes=2), np.eye(4))
    for k in range(50):
        f.add_odometry(k * 10_000_000, np.eye(4))
    assert f.add_vloc(100_000_000, np.eye(4), vote_only=True).reason == "awaiting_init"
    assert not f.initialised
    r = f.add_vloc(200_000_000, make_T(np.eye(3), [0.01, 0, 0]), vote_only=True)
    assert r.accepted and r.reason == "initialised" and f.initialised
    far = make_T(np.eye(3), [5.0, 0, 0])
    assert f.add_vloc(300_000_000, far, vote_only=True).reason == "vote_ignored"
    out = f.add_odometry(500_000_000, np.eye(4))
    assert out is not None and np.linalg.norm(out.T_map_base[:3, 3]) < 0.05  # the ignored vote moved nothing
    s = f.stats()
    assert s["votes"] == 3 and s["vloc"] == 0 and s["vloc_by_reason"]["vote_initialised"] == 1


def test_votes_farther_apart_than_the_window_do_not_combine() -> None:
    """Initialisation votes combine within `init_window_s` (capture stamps); farther apart only
    where the odometry between them stayed within `init_window_m` / `init_window_deg`: the same
    pose voted again after the robot turned (an alias seen again at one heading) does not
    initialise, two consecutive ones do."""
    f = OnlineFusion(FusionParams(init_votes=2, init_window_s=5.0), np.eye(4))
    t_odom = 0

    def odom(t_ns: int) -> np.ndarray:  # turning in place at 0.5 rad/s
        return make_T(so3_exp(np.array([0.0, 0.0, 0.5 * t_ns * 1e-9])), [0, 0, 0])

    def vote(t_ns: int, x: float) -> str:
        nonlocal t_odom
        while t_odom <= t_ns + 10_000_000:  # odometry up to just after the capture
            f.add_odometry(t_odom, odom(t_odom))
            t_odom += 10_000_000
        T_map_odom = make_T(np.eye(3), [x, 0, 0])  # every vote claims (nearly) the same T_map_odom
        return f.add_vloc(t_ns, T_map_odom @ odom(t_ns), vote_only=True).reason

    assert vote(100_000_000, 0.0) == "awaiting_init"
    assert vote(6_100_000_000, 0.01) == "awaiting_init"  # 6 s and 172 deg later: the first vote has expired
    assert not f.initialised
    assert vote(9_000_000_000, 0.02) == "initialised" and f.initialised  # 2.9 s after the second


def test_a_first_fix_slower_than_the_window_still_initialises_a_robot_at_rest() -> None:
    """A global localization that takes 30 s per try under load: its votes are captured 30 s
    apart. At rest they combine (and 30 s of buffered odometry are there to place them); the
    same votes 30 s apart while the robot drives 6 m do not; older than the odometry buffer,
    a vote is refused as too old."""
    def run(speed: float, buffer_s: float = 60.0) -> list[str]:
        f = OnlineFusion(FusionParams(init_votes=2, odom_buffer_s=buffer_s), np.eye(4))
        out, t_odom = [], 0
        for capture, arrive in ((1_000_000_000, 31_000_000_000), (31_000_000_000, 61_000_000_000)):
            while t_odom <= arrive:
                f.add_odometry(t_odom, make_T(np.eye(3), [speed * t_odom * 1e-9, 0, 0]))
                t_odom += 10_000_000
            T_map_base = make_T(np.eye(3), [5.0 + speed * capture * 1e-9, 0, 0])  # T_map_odom = x + 5 m
            out.append(f.add_vloc(capture, T_map_base, vote_only=True).reason)
        return out

    assert run(0.0) == ["awaiting_init", "initialised"]
    assert run(0.2) == ["awaiting_init", "awaiting_init"]  # 6 m driven between the captures
    assert run(0.0, buffer_s=20.0) == ["too_old", "too_old"]
    with pytest.raises(ValueError, match="init_window_m"):
        FusionParams(init_window_m=0.0)
    with pytest.raises(ValueError, match="init_window_s"):
        FusionParams(init_window_s=0.0)


def test_deferred_keyframe_update_answers_first_and_changes_nothing_else(session: dict) -> None:
    """`add_odometry(defer_update=True)` returns the pose from the current estimate and leaves the
    keyframe's smoother update for `flush()`: the same keyframes; a message that makes a keyframe
    due gets the estimate before that update (the one before it: iSAM2 converges over updates),
    so it differs by what the update moves, and the trajectory is as accurate."""
    p = FusionParams()
    vl = simulate_vloc(session["gt_t"], session["T_wb"] @ T_BC, 1.0, p.vloc_sigma_trans, p.vloc_sigma_rot_deg, 0.0,
                       seed=3)
    runs = []
    for defer in (False, True):
        f = OnlineFusion(p, T_BC)
        out: list[np.ndarray] = []
        gt: list[np.ndarray] = []
        gt_all: list[int] = []
        order = np.argsort(vl.t_arrival_ns, kind="stable")
        vi = 0
        for t, T in zip(session["ot"], session["oT"], strict=True):
            while vi < len(order) and vl.t_arrival_ns[order[vi]] <= t:
                k = order[vi]
                f.add_vloc(int(vl.t_capture_ns[k]), vl.T_map_camera[k])
                vi += 1
            keys_before = f.stats()["keyframes"] if defer else None
            r = f.add_odometry(int(t), T, defer_update=defer)
            if defer:
                assert f.stats()["keyframes"] == keys_before  # nothing solved before the answer
                f.flush()
            if r is not None:
                out.append(r.T_map_base)
                gt.append(session["gt_o"][len(gt_all)])
            gt_all.append(0)
        runs.append((np.stack(out), np.stack(gt), f.stats()["keyframes"]))
    (a, ga, ka), (b, gb, kb) = runs
    assert ka == kb > 100 and len(a) == len(b)
    d = np.linalg.norm(a[:, :3, 3] - b[:, :3, 3], axis=1)
    assert np.median(d) == 0.0 and float(np.percentile(d, 99)) < 0.01 and float(d.max()) < 0.03
    ate_a, ate_b = ate(a, ga, align=False).rmse, ate(b, gb, align=False).rmse
    print(f"deferred vs immediate: diff p50 {np.median(d):.4f} p99 {np.percentile(d, 99):.4f} max {d.max():.4f} m; "
          f"ATE {ate_b:.4f} vs {ate_a:.4f} m")
    assert ate_b < 1.02 * ate_a


def test_a_fix_older_than_the_window_is_carried_by_the_odometry_since_its_capture() -> None:
    """After initialisation, a VLoc pose that took 20 s (a loaded computer) is older than the
    smoother's 3 s window: the odometry carries it to the window's oldest state and it corrects
    the fused pose, at rest fully, after 2 m of driving less (the carrying adds that odometry's
    noise); driven out 2 m and back, the noise is the 4 m path's, not the net motion's; past
    `late_max_travel_m` (5 m) it is refused as too old, as is every such pose with it 0."""
    def run(x_at: Callable[[float], float], **kw: float) -> tuple[str, float]:
        f = OnlineFusion(FusionParams(init_votes=1, **kw), np.eye(4))
        f.add_odometry(0, np.eye(4))
        assert f.add_vloc(0, np.eye(4)).reason == "initialised"  # T_map_odom = identity
        for k in range(1, 2101):  # 21 s of odometry at 100 Hz
            f.add_odometry(k * 10_000_000, make_T(np.eye(3), [x_at(k * 0.01), 0, 0]))
        # captured at 1 s: the robot was 0.2 m further along than the start's fix said
        r = f.add_vloc(1_000_000_000, make_T(np.eye(3), [x_at(1.0) + 0.2, 0, 0]))
        out = f.add_odometry(2101 * 10_000_000, make_T(np.eye(3), [x_at(21.01), 0, 0]))
        assert out is not None
        return r.reason, float(out.T_map_base[0, 3] - x_at(21.01))

    def out_and_back(t: float) -> float:  # 2 m out from 1 s to 11 s, back by 21 s
        return 0.2 * float(np.clip(t - 1.0, 0.0, 10.0)) - 0.2 * float(np.clip(t - 11.0, 0.0, 10.0))

    reason, at_rest = run(lambda t: 0.0)
    assert reason == "accepted" and at_rest > 0.03  # the fused pose moved toward the late fix's 0.2 m
    reason, driven = run(lambda t: 0.1 * t)  # 2 m since the capture
    assert reason == "accepted" and 0.005 < driven < 0.8 * at_rest
    reason, there_and_back = run(out_and_back)  # net 0 m, 4 m driven
    assert reason == "accepted" and there_and_back < 0.5 * at_rest
    assert run(lambda t: 0.3 * t)[0] == "too_old"  # 6 m driven since the capture
    reason, shift = run(lambda t: 0.0, late_max_travel_m=0.0)
    assert reason == "too_old" and abs(shift) < 1e-3
    with pytest.raises(ValueError, match="late_max_travel_m"):
        FusionParams(late_max_travel_m=-1.0)


def _biased_drive(t: float, speed: float, yaw_bias_deg_per_m: float) -> np.ndarray:
    """T_odom_base at `t` s of a straight drive along x at `speed` m/s, as an odometry whose
    heading drifts by `yaw_bias_deg_per_m` per metre reports it (an arc)."""
    s, b = speed * t, math.radians(yaw_bias_deg_per_m)
    x, y = (math.sin(b * s) / b, (1 - math.cos(b * s)) / b) if b else (s, 0.0)
    return make_T(so3_exp(np.array([0.0, 0.0, b * s])), [x, y, 0.0])


def test_after_a_long_outage_agreeing_fixes_reanchor_a_drifted_filter() -> None:
    """VLoc corrects a straight 0.5 m/s drive every 0.5 s for 10 s, then is out for 60 s (30 m)
    while the odometry's heading drifts 0.5 deg/m: the fused pose ends ~4 m off, far beyond what
    the graph's random-walk odometry noise allows, so every correct fix used to be gated for
    good. With the drift since the last fix in the gate, the first correct fix votes and the
    next, agreeing, restarts the filter where they say; an alias among them (inside the gate that
    30 m of drift opens) agrees with neither neighbour, so it only delays the restart by a fix."""
    def true_x(t: float) -> float:
        return 0.5 * t

    f = OnlineFusion(FusionParams(), np.eye(4))
    reasons: list[str] = []
    t_fixes = [0.5 * k for k in range(1, 21)] + [72.0, 73.0, 75.0, 77.0, 78.0]
    alias_at = 73.0  # 2 m to the left of the truth
    fix = iter(t_fixes)
    t_next = next(fix)
    sigma_xy: dict[float, float] = {}  # the fused pose's horizontal sigma (m) at some times
    for k in range(1, 8001):  # 80 s at 100 Hz
        t = k * 0.01
        out = f.add_odometry(k * 10_000_000, _biased_drive(t, 0.5, 0.5))
        if k in (1000, 7100, 8000):
            assert out is not None
            sigma_xy[t] = math.sqrt(float(out.covariance[:2, :2].trace()) / 2)
        if abs(t - t_next) < 1e-6:
            y = 2.0 if t == alias_at else 0.0
            reasons.append(f.add_vloc(k * 10_000_000, make_T(np.eye(3), [true_x(t), y, 0.0])).reason)
            t_next = next(fix, math.inf)
    assert out is not None
    assert reasons[:20].count("accepted") >= 18
    assert reasons[20:] == ["reanchor_vote"] * 3 + ["reanchored", "accepted"], reasons[20:]
    err = out.T_map_base[:3, 3] - [true_x(80.0), 0.0, 0.0]
    assert float(np.linalg.norm(err)) < 0.15, err
    assert f.stats()["vloc_by_reason"]["reanchored"] == 1
    # the reported uncertainty grows with the odometry's drift during the outage (30 m: metres)
    assert sigma_xy[10.0] < 0.1 and sigma_xy[71.0] > 2.0 and sigma_xy[80.0] < 0.2, sigma_xy


def test_votes_agree_where_the_robot_is_however_far_the_odometry_origin() -> None:
    """Two fixes 1 deg apart in heading, 0.1 s apart, 100 m from where the odometry started:
    their T_map_odom differ by 1.7 m (the heading difference times 100 m), yet they are the
    same pose within 0.5 m and 10 deg where the robot is, so they initialise the filter."""
    f = OnlineFusion(FusionParams(init_votes=2), np.eye(4))
    for k in range(1, 101):
        f.add_odometry(k * 10_000_000, make_T(np.eye(3), [100.0, 0.0, 0.0]))
    at = make_T(np.eye(3), [3.0, 1.0, 0.0])
    assert f.add_vloc(900_000_000, at).reason == "awaiting_init"
    turned = make_T(so3_exp(np.array([0.0, 0.0, math.radians(1.0)])), [3.0, 1.0, 0.0])
    assert f.add_vloc(1_000_000_000, turned).reason == "initialised"


def test_after_an_outage_with_a_turn_fixes_reanchor_where_the_drift_lies_along_the_track() -> None:
    """Fixes every 0.5 s for 10 s of a 1 m/s drive along x, then none while it drives 60 m on,
    turns left on the spot and drives 6 m along y, the odometry's heading drifting 0.5 deg per
    metre: the first leg's sideways error (~16 m) now lies along the track, where a drift model
    in base_link (sideways b L^2 / 2, along-track only the 2 % scale) gated every correct fix.
    Counted in the odometry frame, the drift is where the path put it: the first correct fix
    votes, the second re-anchors, the third is accepted."""
    b = math.radians(0.5)
    true_pose, odo_pose = np.zeros(3), np.zeros(3)  # (x, y, heading)
    f = OnlineFusion(FusionParams(), np.eye(4))
    fixes = [0.5 * k for k in range(1, 21)] + [80.0, 81.0, 82.0]
    reasons: list[str] = []
    out = None
    for k in range(1, 8301):  # 83 s at 100 Hz
        t = k * 0.01
        ds = 0.01 if t <= 70.0 or 72.0 < t <= 78.0 else 0.0  # 70 m along x, 6 m along y, stop
        dth = math.radians(45.0) * 0.01 if 70.0 < t <= 72.0 else 0.0  # 90 deg on the spot
        for pose, bias in ((true_pose, 0.0), (odo_pose, b)):
            pose[2] += dth + bias * ds
            pose[:2] += ds * np.array([math.cos(pose[2]), math.sin(pose[2])])
        out = f.add_odometry(
            k * 10_000_000, make_T(so3_exp(np.array([0.0, 0.0, odo_pose[2]])), [*odo_pose[:2], 0.0])
        )
        if any(abs(t - tf) < 1e-6 for tf in fixes):
            T_true = make_T(so3_exp(np.array([0.0, 0.0, true_pose[2]])), [*true_pose[:2], 0.0])
            reasons.append(f.add_vloc(k * 10_000_000, T_true).reason)
    assert out is not None
    assert reasons[:20].count("accepted") >= 18
    assert reasons[20:] == ["reanchor_vote", "reanchored", "accepted"], reasons[20:]
    np.testing.assert_allclose(true_pose, [70.0, 6.0, math.pi / 2], atol=1e-6)
    assert float(np.linalg.norm(out.T_map_base[:2, 3] - true_pose[:2])) < 0.15
