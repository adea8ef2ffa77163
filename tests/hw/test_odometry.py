from __future__ import annotations

import time

import numpy as np
import pytest

from litevloc.base.geometry import make_T, so3_exp
from litevloc.base.params.odometry import OdometryCheckParams
from litevloc.config.schema import ZenohConfig
from litevloc.hw import ros_msgs
from litevloc.hw.messages import Odometry
from litevloc.hw.odometry import OdometryChecker, OdometryReceiver, OdometrySender, encode_odometry
from litevloc.runtime.service.queues import BoundedFifo
from litevloc.runtime.transport.bus import Bus
from tests.runtime.zenoh_helpers import free_port

S = 1_000_000_000


def odom(t_ns: int, T: np.ndarray | None = None, cov: np.ndarray | None = None, frame: str = "odom",
         child: str = "base_link") -> bytes:
    return encode_odometry(Odometry(t_ns, np.eye(4) if T is None else T, cov, frame, child))


def raw(t_ns: int, q: tuple[float, float, float, float], p: tuple[float, float, float] = (0, 0, 0)) -> bytes:
    msg = ros_msgs.odometry_msg(t_ns, np.eye(4), "odom", "base_link")
    o, pos = msg.pose.pose.orientation, msg.pose.pose.position
    o.x, o.y, o.z, o.w = q
    pos.x, pos.y, pos.z = p
    return ros_msgs.serialize(msg, ros_msgs.ODOMETRY)


def test_round_trip_and_covariance() -> None:
    T = make_T(so3_exp(np.array([0.1, -0.2, 0.3])), np.array([1.0, 2.0, 3.0]))
    cov = np.diag([0.1, 0.2, 0.3, 0.01, 0.02, 0.03])
    c = OdometryChecker()
    o = c.check_payload(odom(5 * S, T, cov))
    assert o is not None and o.t_ns == 5 * S and np.allclose(o.T_odom_base, T) and np.allclose(o.covariance, cov)
    o2 = c.check_payload(odom(5 * S + 1, T))  # all-zero covariance = unknown
    assert o2 is not None and o2.covariance is None
    assert c.report()["accepted"] == 2 and c.report()["skipped_total"] == 0


def test_bad_messages_are_counted_and_skipped() -> None:
    c = OdometryChecker(OdometryCheckParams(max_gap_s=0.1))
    good = odom(10 * S)
    assert c.check_payload(good) is not None
    assert c.check_payload(good[:20]) is None  # truncated CDR
    assert c.check_payload(b"\x00\x01garbage") is None
    assert c.check_payload(raw(11 * S, (0, 0, 0, float("nan")))) is None
    assert c.check_payload(raw(11 * S, (0, 0, 0, 1), (float("inf"), 0, 0))) is None
    assert c.check_payload(raw(11 * S, (0, 0, 0, 1.1))) is None
    assert c.check_payload(raw(11 * S, (0, 0, 0, 1.0005))) is not None  # renormalised within tolerance
    assert c.check_payload(odom(9 * S)) is None  # backwards
    assert c.check_payload(odom(11 * S)) is None  # duplicate
    assert c.check_payload(odom(12 * S, frame="other_odom")) is None  # frame changed (locked in)
    bad_cov = np.eye(6)
    bad_cov[0, 1] = 5.0  # not symmetric
    o = c.check_payload(odom(int(11.05 * S), cov=bad_cov))
    assert o is not None and o.covariance is None
    r = c.report()
    assert r["skipped"] == {"malformed_cdr": 2, "nan_pose": 2, "non_unit_quaternion": 1, "time_backwards": 1,
                            "duplicate_stamp": 1, "frame_id_mismatch": 1}
    assert r["bad_covariance"] == 1 and r["accepted"] == 3 and r["received"] == 11
    assert r["gaps"] == 1 and r["flagged"] and r["last_gap_s"] == pytest.approx(1.0)  # 10 s -> 11 s
    c.clear_flag()
    assert not c.report()["flagged"]


def test_child_frame_and_extrinsics() -> None:
    T_child_base = make_T(so3_exp(np.array([0, 0, np.pi / 2])), np.array([0.2, 0.0, -0.1]))
    p = OdometryCheckParams(child_frame_id="imu_link", T_child_base=tuple(T_child_base.reshape(-1)))
    c = OdometryChecker(p)
    T = make_T(so3_exp(np.array([0, 0, 0.5])), np.array([1.0, 0, 0]))
    o = c.check_payload(odom(1 * S, T, child="imu_link"))
    assert o is not None and np.allclose(o.T_odom_base, T @ T_child_base) and o.child_frame_id == "base_link"
    assert c.check_payload(odom(2 * S, T, child="base_link")) is None
    assert c.report()["skipped"] == {"child_frame_id_mismatch": 1}
    with pytest.raises(ValueError, match="16 numbers"):
        OdometryCheckParams(T_child_base=(1.0, 0.0))
    with pytest.raises(ValueError):
        OdometryCheckParams(max_gap_s=0)


@pytest.mark.timeout(30)
def test_receive_over_zenoh_never_loses_a_message() -> None:
    port = free_port()
    ep = f"tcp/127.0.0.1:{port}"
    fifo: BoundedFifo[Odometry] = BoundedFifo("odometry", capacity=10_000)
    with Bus(ZenohConfig(listen=(ep,))) as rx_bus, Bus(ZenohConfig(listen=(), connect=(ep,))) as tx_bus:
        rx = OdometryReceiver(rx_bus.session, "robot/odom", fifo.put)
        tx = OdometrySender(tx_bus.session, "robot/odom")
        # not a fixed sleep: under load the subscription took > 0.3 s to propagate and the first
        # ~130 puts went nowhere (Zenoh drops a put that no subscriber matches yet)
        assert tx.wait_for_subscribers(10.0)
        n = 1000
        for i in range(n):
            tx.send(Odometry((i + 1) * 5_000_000, make_T(np.eye(3), np.array([i * 0.01, 0, 0]))))
        tx.send_raw(b"not cdr")
        t_end = time.monotonic() + 10
        while rx.report()["received"] < n + 1 and time.monotonic() < t_end:
            time.sleep(0.01)
        r = rx.report(stale_after_s=5.0)
        assert r["received"] == n + 1 and r["accepted"] == n and r["skipped"] == {"malformed_cdr": 1}
        assert not r["stale"] and r["sink_errors"] == 0
        got = [fifo.get_nowait() for _ in range(n)]
        assert [o.t_ns for o in got] == [(i + 1) * 5_000_000 for i in range(n)]
        fifo.close()  # a sink failing (queue closed at shutdown) is counted, not raised into Zenoh
        tx.send(Odometry((n + 5) * 5_000_000, np.eye(4)))
        t_end = time.monotonic() + 5
        while rx.sink_errors == 0 and time.monotonic() < t_end:
            time.sleep(0.01)
        assert rx.sink_errors == 1 and "closed" in (rx.last_sink_error or "")
        rx.close()
        tx.close()
