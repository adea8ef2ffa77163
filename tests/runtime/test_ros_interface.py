"""The ROS 2 robot interface end to end: `/tf` against the published fused pose, `/initialpose`
bounding global localization, refusals."""

from __future__ import annotations

import dataclasses
import threading
import time
from typing import Any

import numpy as np
import pytest

from litevloc.base.geometry import (
    gtsam_to_ros_covariance,
    invert,
    make_T,
    quat_xyzw_to_matrix,
    relative_pose_error,
    so3_exp,
)
from litevloc.base.params.drift import T_BASE_CAMERA_OPTICAL
from litevloc.base.params.fusion import FusionParams
from litevloc.config.schema import InitialPoseConfig, RuntimeConfig, ZenohConfig
from litevloc.hw import ros_msgs
from litevloc.pipelines.fusion.online import OnlineFusion
from litevloc.pipelines.localization.search_region import SearchRegion, nodes_within
from litevloc.pipelines.localization.tracking import TrackingState
from litevloc.pipelines.localization.vloc import VisualLocalizer
from litevloc.runtime.service.core import FusionPort, LocalizationCore
from litevloc.runtime.service.fusion_port import fusion_port
from litevloc.runtime.service.shell import Service, ServicePorts, localizer_callable
from litevloc.runtime.transport.bus import Bus, LiteVLocPublisher
from litevloc.runtime.transport.ros_inputs import InitialPoseInput
from litevloc.runtime.transport.ros_interface import TF_MESSAGE, InitialPoseRefused, parse_initial_pose
from tests.pipelines.localization.test_vloc import IMG, PARAMS, K, Scene, make_map, pose
from tests.runtime.fakes import T_MAP_ODOM_TRUE, FakeFusion, Result, SyntheticSource, T_odom_base_at
from tests.runtime.rmw_zenoh_reference import REFERENCE_HASHES, parse_attachment
from tests.runtime.test_rmw_zenoh import RosNodeView
from tests.runtime.zenoh_helpers import free_port


class NoisyVloc:
    """The true camera pose with a few cm / tenths of a degree of noise: every fix moves map->odom."""

    def __init__(self) -> None:
        self.rng = np.random.default_rng(3)

    def __call__(self, frame: Any, prior: Any) -> Result:
        T = T_MAP_ODOM_TRUE @ T_odom_base_at(frame.t_ns) @ T_BASE_CAMERA_OPTICAL
        T = T @ make_T(so3_exp(self.rng.normal(0, 0.005, 3)), self.rng.normal(0, 0.03, 3))
        return Result(frame.t_ns, True, "ok", T, np.eye(6) * 1e-3)


def _tf_matrix(tr: Any) -> np.ndarray:
    q, t = tr.transform.rotation, tr.transform.translation
    return make_T(quat_xyzw_to_matrix(np.array([q.x, q.y, q.z, q.w])), np.array([t.x, t.y, t.z]))


@pytest.mark.timeout(60)
def test_tf_map_to_odom_composed_with_odometry_is_the_published_pose() -> None:
    port = free_port()
    cfg = ZenohConfig(listen=(f"tcp/127.0.0.1:{port}",), ros2="rmw_zenoh")
    with Bus(cfg) as bus:
        pub = LiteVLocPublisher(bus)
        view = RosNodeView(port)
        try:
            k_pose = view.subscribe(0, "/litevloc/pose", ros_msgs.ODOMETRY)
            k_tf = view.subscribe(0, "/tf", TF_MESSAGE)
            assert all(p.wait_for_subscribers(5.0) for p in (pub.pubs["pose"], pub.pubs["tf"]))
            src = SyntheticSource(seconds=3.0, odom_hz=100.0, frame_hz=5.0)
            fusion = OnlineFusion(FusionParams(), T_BASE_CAMERA_OPTICAL)
            port = dataclasses.replace(fusion_port(fusion), covariance_to_ros=gtsam_to_ros_covariance)
            core = LocalizationCore(port, RuntimeConfig(mode="deterministic"))
            svc = Service(src, NoisyVloc(), core, ServicePorts(pub), configure_thread_counts=False)
            res = svc.run(timeout_s=40)
            assert res.ok, res.reason
            n_tf = res.status["counters"]["map_to_odom_published"]
            poses = {}
            for payload, _ in view.wait(k_pose, res.status["counters"]["poses_published"]):
                t, T, _ = ros_msgs.odometry_to_matrix(ros_msgs.deserialize(payload, ros_msgs.ODOMETRY))
                poses[t] = T
            tfs = view.wait(k_tf, n_tf)
            assert n_tf >= 10
            moved = []
            for payload, att in tfs:
                (tr,) = ros_msgs.deserialize(payload, TF_MESSAGE).transforms
                assert (tr.header.frame_id, tr.child_frame_id) == ("map", "odom")
                t = ros_msgs.stamp_ns(tr.header)
                T_map_odom = _tf_matrix(tr)
                moved.append(T_map_odom)
                dt, dr_deg = relative_pose_error(T_map_odom @ T_odom_base_at(t), poses[t])
                assert dt < 1e-3 and dr_deg < 0.01, (t, dt, dr_deg)
                assert parse_attachment(att)[0] >= 1
            # the fixes move map->odom: a stale transform would not compose to the pose
            assert max(np.linalg.norm(m[:3, 3] - moved[0][:3, 3]) for m in moved) > 0.005
        finally:
            view.close()
            pub.close()


def _initial_pose_msg(x: float, y: float, frame: str = "map", sigma: float = 0.5, nan: bool = False) -> bytes:
    cov = np.zeros((6, 6))
    cov[0, 0] = cov[1, 1] = sigma ** 2
    cov[5, 5] = 0.07
    T = make_T(so3_exp(np.array([0.0, 0.0, 0.3])), np.array([x, y, 0.0]))
    if nan:
        T[0, 3] = np.nan
    msg = ros_msgs.pose_cov_stamped_msg(123, T if not nan else np.eye(4), frame, cov)
    if nan:
        msg.pose.pose.position.x = float("nan")
    return ros_msgs.serialize(msg, ros_msgs.POSE_COV_STAMPED)


def test_search_region_filter_keeps_order() -> None:
    positions = np.array([[0.0, 0, 0], [10, 0, 0], [20, 0, 0], [21, 1, 0], [19, -1.5, 5]])
    order = np.array([1, 0, 4, 3, 2])
    assert nodes_within(order, positions, SearchRegion(np.array([20.0, 0.0]), 2.0)).tolist() == [4, 3, 2]
    assert nodes_within(order, positions, SearchRegion(np.array([50.0, 0.0]), 2.0)).tolist() == []
    with pytest.raises(ValueError):
        SearchRegion(np.array([np.nan, 0.0]), 1.0)


def test_initial_pose_refusals() -> None:
    p = InitialPoseConfig()
    ok = parse_initial_pose(ros_msgs.deserialize(_initial_pose_msg(3, 4), ros_msgs.POSE_COV_STAMPED), "map", p)
    assert np.allclose(ok.T_map_base[:2, 3], [3, 4]) and ok.radius_m == pytest.approx(2.0)
    wide = parse_initial_pose(ros_msgs.deserialize(_initial_pose_msg(3, 4, sigma=2.0), ros_msgs.POSE_COV_STAMPED),
                              "map", p)
    assert wide.radius_m == pytest.approx(6.0)
    for payload, match in ((_initial_pose_msg(0, 0, frame="odom"), "frame_id"),
                           (_initial_pose_msg(0, 0, nan=True), "NaN"),
                           (_initial_pose_msg(0, 0, sigma=100.0), "bounds nothing")):
        with pytest.raises(InitialPoseRefused, match=match):
            parse_initial_pose(ros_msgs.deserialize(payload, ros_msgs.POSE_COV_STAMPED), "map", p)


def _tracking_localizer() -> tuple[VisualLocalizer, Scene]:
    """A localizer that tracked near x = 1 m on a map with keyframes near 0-3 m and 20-23 m."""
    m = make_map([0.0, 1.0, 2.0, 3.0, 20.0, 21.0, 22.0, 23.0])
    s = Scene(m)
    loc = VisualLocalizer(m, PARAMS, s.extract, s.describe, s.match)
    r = loc.process(0, IMG, s.look(pose(1.2), 1), K)
    assert r.accepted and loc.tracker.state == TrackingState.TRACKING
    return loc, s


def test_initial_pose_20m_from_the_last_fix_bounds_the_next_global_search() -> None:
    loc, s = _tracking_localizer()
    core = LocalizationCore(FusionPort(FakeFusion().add_odometry, FakeFusion().add_vloc))
    inp = InitialPoseInput(_NoBus(), core, ZenohConfig())
    vloc = localizer_callable(loc)
    frame = _Frame(1_000_000_000, s.look(pose(1.4), 1))  # the view looks like the old place (VPR ranks 0-3 first)
    # refused messages are counted and never applied
    assert inp.handle(_initial_pose_msg(21.0, 0.0, frame="odom")) is None
    assert inp.handle(_initial_pose_msg(float("nan"), 0.0, nan=True)) is None
    assert core.prior(frame.t_ns) is None and inp.report()["refused"] == {"wrong_frame": 1, "non_finite": 1}
    assert inp.handle(_initial_pose_msg(21.0, 0.0)) is not None  # 20 m from the last fix at 1.2 m
    prior = core.prior(frame.t_ns)
    assert prior is not None and prior.region is not None
    res = vloc(frame, prior)
    tried = [a.node for a in res.attempts]
    assert tried and all(20.0 - 2.5 <= loc.verifier.map.positions[n, 0] <= 23.0 for n in tried), tried
    assert loc.tracker.state != TrackingState.TRACKING or res.accepted
    # without the initial pose the same query searches near the old fix
    loc2, _ = _tracking_localizer()
    loc2.tracker.state = TrackingState.GLOBAL
    res2 = loc2.localize_global(frame.t_ns, IMG, frame.depth, K)
    assert all(loc2.verifier.map.positions[a.node, 0] <= 3.0 for a in res2.attempts)
    assert inp.report()["applied"] == 1 and core.counters["initial_poses_applied"] == 1


def test_initial_pose_is_held_until_a_fix_from_a_bounded_query_then_released() -> None:
    core = LocalizationCore(FusionPort(FakeFusion().add_odometry, FakeFusion().add_vloc))
    inp = InitialPoseInput(_NoBus(), core, ZenohConfig())
    inp.handle(_initial_pose_msg(21.0, 0.0))
    core.vloc_result(Result(5, True, "ok", np.eye(4)))  # a fix in flight before the initial pose: not the answer
    assert core.prior(10) is not None and core.prior(10).region is not None  # type: ignore[union-attr]
    core.vloc_result(Result(10, True, "ok", np.eye(4)))
    assert core.prior(20) is None  # released: fusion's prior takes over (none here)


class _NoBus:
    def subscribe_topic(self, *_: Any, **__: Any) -> Any:
        return None


class _Frame:
    def __init__(self, t_ns: int, depth: np.ndarray) -> None:
        self.t_ns, self.color, self.depth, self.K = t_ns, IMG, depth, K


@pytest.mark.timeout(30)
def test_initial_pose_over_rmw_zenoh_reaches_the_core() -> None:
    """Published as an rmw_zenoh node would (its key, its attachment), applied by the runtime."""
    port = free_port()
    core = LocalizationCore(FusionPort(FakeFusion().add_odometry, FakeFusion().add_vloc))
    with Bus(ZenohConfig(listen=(f"tcp/127.0.0.1:{port}",), ros2="rmw_zenoh", namespace="r2")) as bus:
        inp = InitialPoseInput(bus, core, bus.cfg)
        view = RosNodeView(port)
        try:
            key = ("0/r2/initialpose/geometry_msgs::msg::dds_::PoseWithCovarianceStamped_/"
                   + REFERENCE_HASHES[ros_msgs.POSE_COV_STAMPED])
            rviz = view.session.declare_publisher(key)
            deadline = time.monotonic() + 5
            while not rviz.matching_status.matching and time.monotonic() < deadline:
                time.sleep(0.01)
            from litevloc.runtime.transport.rmw_zenoh import attachment

            rviz.put(_initial_pose_msg(5.0, -2.0), attachment=attachment(1, time.time_ns(), bytes(16)))
            done = threading.Event()
            while not done.wait(0.01) and time.monotonic() < deadline:
                if inp.report()["applied"]:
                    done.set()
            assert inp.report()["applied"] == 1
            prior = core.prior(0)
            assert prior is not None and prior.region is not None
            assert np.allclose(prior.region.center_xy, (make_T(np.eye(3), np.array([5.0, -2, 0])) @
                                                        T_BASE_CAMERA_OPTICAL)[:2, 3], atol=1e-9)
            tokens = view.tokens(0)
            assert any("/MS/%/%r2/litevloc/%r2%initialpose/" in t for t in tokens), tokens
        finally:
            view.close()


def test_inverse_of_tf_helpers() -> None:
    T = make_T(so3_exp(np.array([0.1, -0.2, 0.3])), np.array([1.0, 2.0, 3.0]))
    tr = ros_msgs.transform_stamped_msg(0, T, "a", "b")
    assert np.allclose(_tf_matrix(tr), T) and np.allclose(invert(invert(T)), T)
