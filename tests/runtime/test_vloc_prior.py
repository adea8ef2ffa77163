"""The VLoc prior at the frame's stamp (T_map_odom @ odometry interpolated at t_frame) with its age."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from litevloc.base.geometry import relative_pose_error
from litevloc.base.params.drift import T_BASE_CAMERA_OPTICAL
from litevloc.base.params.fusion import FusionParams
from litevloc.config.schema import RuntimeConfig
from litevloc.hw.messages import Odometry, RgbdFrame
from litevloc.pipelines.fusion.online import OnlineFusion
from litevloc.pipelines.localization.prior import Prior
from litevloc.runtime.service.core import FusionPort, LocalizationCore
from litevloc.runtime.service.fusion_port import fusion_port
from litevloc.runtime.service.shell import Service, ServicePorts
from litevloc.runtime.service.vloc_prior import OdometryHistory, VlocPrior, prior_at
from tests.runtime.fakes import (
    MS,
    T_MAP_ODOM_TRUE,
    FakeFusion,
    FakePublisher,
    Result,
    T_odom_base_at,
    Update,
    make_service,
)


def test_history_interpolates_and_clamps_at_the_ends() -> None:
    h = OdometryHistory(capacity=50)
    assert h.at(0) is None
    for k in range(120):  # wraps the ring twice
        h.add(k * 10 * MS, T_odom_base_at(k * 10 * MS))
    h.add(500 * MS, np.eye(4))  # not newer than the last: ignored
    assert len(h) == 50
    T, t = h.at(1105 * MS)  # between two samples
    assert t == 1105 * MS
    dt, dr = relative_pose_error(T, T_odom_base_at(1105 * MS))
    assert dt < 1e-3 and dr < 0.01
    T, t = h.at(0)  # older than the history (the first 70 were overwritten): the oldest kept
    assert t == 700 * MS and np.allclose(T, T_odom_base_at(700 * MS))
    T, t = h.at(5000 * MS)  # newer: the newest
    assert t == 1190 * MS
    p = prior_at(5000 * MS, np.eye(4), h, np.eye(4), last_fix_ns=1000 * MS)
    assert p is not None and not p.interpolated
    assert p.age_s == pytest.approx(4.0 + (5000 - 1190) * 1e-3)  # since the fix, plus the gap


def test_history_odometer_measures_the_path_between_two_stamps() -> None:
    """The path, not the displacement: 1 m out and 1 m back is 2 m; a stamp outside the kept
    history gives None (the path there is unknown), and so does a prior whose fix is that old."""
    h = OdometryHistory(capacity=300)
    for k in range(201):  # 0.01 m per 10 ms out along x for 1 s, then back
        x = k * 0.01 if k <= 100 else (200 - k) * 0.01
        h.add(k * 10 * MS, np.array([[1, 0, 0, x], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]]))
    assert h.travel(0, 2000 * MS) == pytest.approx(2.0)
    assert h.travel(500 * MS, 1505 * MS) == pytest.approx(1.005)
    assert h.travel(1000 * MS, 1000 * MS) == 0.0
    assert h.travel(0, 2001 * MS) is None
    p = prior_at(1500 * MS, np.eye(4), h, np.eye(4), last_fix_ns=500 * MS)
    assert p is not None and p.travel_m == pytest.approx(1.0) and p.age_s == pytest.approx(1.0)
    for k in range(201, 500):  # at rest; the first samples leave the ring
        h.add(k * 10 * MS, np.eye(4))
    assert h.travel(100 * MS, 4000 * MS) is None
    p = prior_at(4900 * MS, np.eye(4), h, np.eye(4), last_fix_ns=2500 * MS)
    assert p is not None and p.travel_m == pytest.approx(0.0) and p.age_s == pytest.approx(2.4)
    p = prior_at(4900 * MS, np.eye(4), h, np.eye(4), last_fix_ns=100 * MS)
    assert p is not None and p.travel_m is None


def test_delayed_frame_gets_the_pose_at_its_stamp_and_its_true_age() -> None:
    """The frame VLoc takes is 0.5 s older than the newest odometry: its prior is where the
    robot was then (the latest fused pose is 0.25 m and 9 deg further on), and its age counts
    from the last fix."""
    fusion = FakeFusion()
    svc = make_service([], lambda f, p: None, fusion, FakePublisher(), RuntimeConfig(mode="sequential"))
    t_fix = 100 * MS
    for k in range(0, 201):  # odometry at 200 Hz for 1 s
        t = k * 5 * MS + 1
        svc._handle_odometry_item((0, Odometry(t, T_odom_base_at(t))))
        if k == 20:  # a VLoc fix at 0.1 s
            T = T_MAP_ODOM_TRUE @ T_odom_base_at(t_fix) @ T_BASE_CAMERA_OPTICAL
            svc._handle_result(Result(t_fix, True, "ok", T, np.eye(6) * 1e-4))
    t_frame = 500 * MS  # newest odometry: 1.0 s
    prior = svc.core.prior(t_frame)
    assert prior is not None and prior.interpolated
    truth = T_MAP_ODOM_TRUE @ T_odom_base_at(t_frame) @ T_BASE_CAMERA_OPTICAL
    dt, dr = relative_pose_error(prior.T_map_camera, truth)
    assert dt < 1e-3 and dr < 0.05
    assert prior.age_s == pytest.approx(0.4)
    latest = svc.core.prior()  # what the service used to hand VLoc: the newest fused pose, age 0 then
    assert latest is not None
    dt, dr = relative_pose_error(latest.T_map_camera, truth)
    assert dt > 0.2 and dr > 5.0
    # the localizer adapter hands both on
    seen: list[tuple[np.ndarray | None, float, np.ndarray | None, float | None]] = []

    class Loc:
        tracker = type("T", (), {"state": "LOCAL"})()

        def process(self, t_ns: int, color: object, depth: object, K: object, prior: Prior | None = None,
                    region: object = None) -> Result:
            assert prior is not None and prior.fused
            seen.append((prior.T_map_camera, prior.age_s, prior.cov, prior.travel_m))
            return Result(t_ns, False, "too few inliers")

    from litevloc.runtime.service.shell import localizer_callable
    frame = RgbdFrame(t_frame, np.zeros((8, 8, 3), np.uint8), None, np.eye(3))
    out = localizer_callable(Loc())(frame, prior)
    assert seen[0][0] is prior.T_map_camera and seen[0][1] == pytest.approx(0.4)
    assert seen[0][3] is not None and seen[0][3] == prior.travel_m and prior.travel_m > 0.1  # the odometry's path
    # fusion's covariance (0.01 m^2 / rad^2 per axis) reaches the camera's position over the lever arm
    assert seen[0][2] is prior.cov_position and prior.cov_position is not None
    assert np.all(np.linalg.eigvalsh(prior.cov_position) >= 0.01 - 1e-9)
    assert out.tracking_state == "LOCAL"  # the localizer's state travels with its result


def test_before_fusion_starts_the_first_fix_is_carried_by_odometry() -> None:
    """The real GTSAM fusion waits for a second agreeing fix and answers no odometry until
    then; meanwhile VLoc's prior is the first fix carried to the frame's stamp by the odometry
    since, aged from the fix (not the pose where the robot was, nor nothing); once fusion
    starts, fusion's prior again."""
    fusion = OnlineFusion(FusionParams(), T_BASE_CAMERA_OPTICAL)
    core = LocalizationCore(fusion_port(fusion), RuntimeConfig(mode="sequential"))
    svc = Service([], lambda f, p: None, core, ServicePorts(FakePublisher()))
    t_fix = 100 * MS
    for k in range(0, 201):  # odometry at 200 Hz for 1 s
        t = k * 5 * MS + 1
        svc._handle_odometry_item((0, Odometry(t, T_odom_base_at(t))))
        if k == 10:
            assert svc.core.prior(t) is None  # no fix yet: nothing to carry
        if k == 20:
            T = T_MAP_ODOM_TRUE @ T_odom_base_at(t_fix) @ T_BASE_CAMERA_OPTICAL
            svc._handle_result(Result(t_fix, True, "ok", T, np.eye(6) * 1e-4))
    assert svc.core.last_fused is None  # fusion has not started
    t_frame = 800 * MS
    prior = svc.core.prior(t_frame)
    assert prior is not None and prior.cov_position is None and prior.age_s == pytest.approx(0.7)
    truth = T_MAP_ODOM_TRUE @ T_odom_base_at(t_frame) @ T_BASE_CAMERA_OPTICAL
    dt, dr = relative_pose_error(prior.T_map_camera, truth)
    assert dt < 1e-3 and dr < 0.05
    assert relative_pose_error(prior.T_map_camera, T)[0] > 0.2  # the robot moved on since the fix
    # a second, agreeing fix starts fusion: its prior (with its covariance) from then on
    svc._handle_result(Result(900 * MS, True, "ok", T_MAP_ODOM_TRUE @ T_odom_base_at(900 * MS) @ T_BASE_CAMERA_OPTICAL,
                              np.eye(6) * 1e-4))
    svc._handle_odometry_item((0, Odometry(1006 * MS, T_odom_base_at(1006 * MS))))
    after = svc.core.prior(t_frame)
    assert after is not None and after.cov_position is not None


def test_the_next_frames_prior_has_the_fix_before_the_fusion_thread_takes_it() -> None:
    """The VLoc thread asks for the next frame's prior while the fusion thread may not yet have
    taken the last result from its queue: the fix is remembered as VLoc returns it."""
    fusion = FakeFusion()
    t_fix = 100 * MS
    T = T_MAP_ODOM_TRUE @ T_odom_base_at(t_fix) @ T_BASE_CAMERA_OPTICAL
    core = LocalizationCore(FusionPort(fusion.add_odometry, lambda r: Update(False, "awaiting_init")),
                            RuntimeConfig(mode="sequential"))
    svc = Service([], lambda f, p: Result(f.t_ns, True, "ok", T, np.eye(6) * 1e-4), core,
                  ServicePorts(FakePublisher()))
    for k in range(0, 201):
        t = k * 5 * MS + 1
        svc._handle_odometry_item((0, Odometry(t, T_odom_base_at(t))))
    assert svc.core.prior(800 * MS) is None
    svc._vloc(RgbdFrame(t_fix, np.zeros((8, 8, 3), np.uint8), None, np.eye(3)))  # its result not handled yet
    prior = svc.core.prior(800 * MS)
    assert prior is not None and prior.age_s == pytest.approx(0.7)
    truth = T_MAP_ODOM_TRUE @ T_odom_base_at(800 * MS) @ T_BASE_CAMERA_OPTICAL
    assert relative_pose_error(prior.T_map_camera, truth)[0] < 1e-3


@pytest.mark.timeout(30)
@pytest.mark.parametrize("wait_ms", [100.0, 0.0])
def test_realtime_next_frames_prior_holds_the_fix_fusion_takes_meanwhile(wait_ms: float) -> None:
    """Realtime: VLoc puts an accepted fix (captured at 0.6 s) in the results queue and takes the
    next frame (1.0 s) at once, while the fusion thread takes that result 30 ms later. The next
    frame's prior waits for it (and for the fused pose after it) and is 0.4 s old, not 0.9 s:
    without the wait (`prior_wait_ms` 0) it is the fix before, and a VLoc slower than the
    robot's prior gate (4 s per call) never had a prior fresh enough to confirm a pose."""
    fusion = FakeFusion()
    priors: list[VlocPrior | None] = []
    shifted = np.eye(4)
    shifted[0, 3] = 0.1  # the fix at 0.6 s says the map is 0.1 m off from where the first one put it

    def vloc_fn(frame: RgbdFrame, prior: VlocPrior | None) -> Result:
        priors.append(prior)
        T = T_MAP_ODOM_TRUE @ T_odom_base_at(frame.t_ns) @ T_BASE_CAMERA_OPTICAL
        return Result(frame.t_ns, True, "ok", shifted @ T if frame.t_ns == 600 * MS else T, np.eye(6) * 1e-4)

    svc = make_service([], vloc_fn, fusion, FakePublisher(), RuntimeConfig(mode="realtime", prior_wait_ms=wait_ms))
    for k in range(0, 201):  # odometry at 200 Hz for 1 s, the first fix at 0.1 s
        t = k * 5 * MS + 1
        svc._handle_odometry_item((0, Odometry(t, T_odom_base_at(t))))
        if k == 20:  # through the results queue, as the VLoc thread hands on every result
            svc._handle_frame(RgbdFrame(100 * MS, np.zeros((8, 8, 3), np.uint8), None, np.eye(3)))
            svc._handle_result(svc.results.get(1.0))
    priors.clear()
    svc._handle_frame(RgbdFrame(600 * MS, np.zeros((8, 8, 3), np.uint8), None, np.eye(3)))

    def fusion_thread() -> None:
        time.sleep(0.03)
        svc._handle_result(svc.results.get(1.0))
        time.sleep(0.01)
        svc._handle_odometry_item((0, Odometry(1005 * MS, T_odom_base_at(1005 * MS))))

    th = threading.Thread(target=fusion_thread)
    th.start()
    svc._vloc(RgbdFrame(1000 * MS, np.zeros((8, 8, 3), np.uint8), None, np.eye(3)))
    th.join()
    assert priors[0] is not None and priors[1] is not None
    ages = [p.age_s for p in priors if p is not None]
    truth = T_MAP_ODOM_TRUE @ T_odom_base_at(1000 * MS) @ T_BASE_CAMERA_OPTICAL
    off = relative_pose_error(priors[1].T_map_camera, truth)[0]
    assert ages[0] == pytest.approx(0.5)  # the frame at 0.6 s: the fix at 0.1 s
    if wait_ms:  # the fix at 0.6 s, its age and its correction
        assert ages[1] == pytest.approx(0.4) and off == pytest.approx(0.1)
        assert svc.shell_counters["prior_waits_timed_out"] == 0
    else:
        assert ages[1] == pytest.approx(0.9) and off < 1e-6
