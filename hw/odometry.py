"""Odometry input over Zenoh: nav_msgs/Odometry (CDR) -> checked `hw.messages.Odometry`.

For robots that publish their proprioceptive odometry (legs, wheels, IMU) on Zenoh
(natively, or from ROS 2 through zenoh-bridge-ros2dds), `OdometryReceiver` subscribes to
a key expression, decodes each CDR payload and runs `OdometryChecker`; accepted messages
go to a sink (the runtime's odometry FIFO). Nothing is silently lost: every skipped
message is counted by reason, and forward time jumps are counted and flagged.

Checks (reason names as they appear in `report()["skipped"]`):

* `malformed_cdr`: the payload does not decode as nav_msgs/Odometry.
* `nan_pose`: position or orientation has NaN/inf.
* `non_unit_quaternion`: |q| differs from 1 by more than `quat_norm_tolerance`
  (within the tolerance the quaternion is renormalised).
* `frame_id_mismatch` / `child_frame_id_mismatch`: header.frame_id / child_frame_id
  differ from the configured ones. With `frame_id: ""` the first message's frame is
  locked in, so a later change (an odometry reset into another frame) is caught too.
* `time_backwards`: stamp earlier than the last accepted one (skipped);
  `duplicate_stamp`: equal to it (skipped).
* Forward jumps larger than `max_gap_s` are ACCEPTED but counted in `gaps`
  (`last_gap_s`, `max_gap_seen_s`), and `flagged` is true until `clear_flag()`:
  the consumer (fusion, status) decides what a gap means (e.g. a larger odometry
  covariance between the two samples).
* A covariance with NaN/inf or a non-symmetric / negative diagonal is dropped (the
  message is kept with `covariance=None`, counted as `bad_covariance`); an all-zero
  covariance means "unknown" in ROS and is passed on as None too (not counted).

Frames and extrinsics. nav_msgs/Odometry gives `T_frame_child` (header.frame_id <-
child_frame_id). LiteVLoc's fusion wants `T_odom_base` with `base_link` the robot body
frame the camera extrinsics `T_base_camera` refer to. When the robot's odometry child
frame is not that base_link (e.g. an IMU or trunk frame), configure `T_child_base`
(pose of base_link in the child frame, 16 floats row-major) and the receiver outputs
`T_odom_base = T_frame_child @ T_child_base`. The `odom` frame stays the robot's
(its origin is wherever the robot put it; fusion estimates `T_map_odom` anyway). If
`T_child_base` is wrong, the mismatch shows up as a rotation-dependent lever-arm error
between VLoc and odometry (fusion rejections grow when the robot turns); it cannot be
detected from odometry alone. The pose covariance is passed through unchanged (not
re-expressed through `T_child_base`): exact for identity extrinsics, an approximation
otherwise.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from litevloc.base.geometry import make_T, quat_xyzw_to_matrix
from litevloc.base.params.odometry import OdometryCheckParams
from litevloc.hw import ros_msgs
from litevloc.hw.messages import Odometry, StreamStats

log = logging.getLogger(__name__)


_WARM = [False]


def _warm_decoder() -> None:
    """rosbags generates its CDR decoder on first use (~0.2 s): do it before the first real message."""
    if not _WARM[0]:
        ros_msgs.deserialize(encode_odometry(Odometry(0, np.eye(4))), ros_msgs.ODOMETRY)
        _WARM[0] = True


class OdometryChecker:
    """Validates decoded odometry in arrival order; counts what it skips and flags gaps.

    Not thread-safe: one checker per input stream, called from one thread (the Zenoh
    callback thread delivers one key expression's samples sequentially).
    """

    def __init__(self, params: OdometryCheckParams | None = None) -> None:
        self.params = params or OdometryCheckParams()
        self.stats = StreamStats()  # messages = received; skipped = by reason
        self.accepted = 0
        self.gaps = 0
        self.last_gap_s = 0.0
        self.max_gap_seen_s = 0.0
        self.flagged = False
        self.bad_covariance = 0
        self.last_t_ns: int | None = None
        self.frame_id: str | None = self.params.frame_id or None
        self._T_child_base = self.params.child_to_base()
        _warm_decoder()

    def clear_flag(self) -> None:
        self.flagged = False

    def check_payload(self, payload: bytes | memoryview) -> Odometry | None:
        """CDR bytes -> checked Odometry, or None (counted) if the message is skipped."""
        self.stats.messages += 1
        try:
            msg = ros_msgs.deserialize(payload, ros_msgs.ODOMETRY)
            _ = msg.header.stamp, msg.pose.pose.orientation, msg.child_frame_id
        except (ros_msgs.MessageDecodeError, AttributeError) as exc:
            self.stats.skip("malformed_cdr")
            log.debug("odometry: %s", exc)
            return None
        return self._check(msg)

    def check_message(self, msg: Any) -> Odometry | None:
        """A decoded nav_msgs/Odometry -> checked Odometry, or None (counted)."""
        self.stats.messages += 1
        return self._check(msg)

    def _check(self, msg: Any) -> Odometry | None:
        p = self.params
        o, pos = msg.pose.pose.orientation, msg.pose.pose.position
        q = np.array([o.x, o.y, o.z, o.w], dtype=np.float64)
        t = np.array([pos.x, pos.y, pos.z], dtype=np.float64)
        if not (np.all(np.isfinite(q)) and np.all(np.isfinite(t))):
            self.stats.skip("nan_pose")
            return None
        if abs(float(np.linalg.norm(q)) - 1.0) > p.quat_norm_tolerance:
            self.stats.skip("non_unit_quaternion")
            return None
        frame = str(msg.header.frame_id)
        if self.frame_id is None:
            self.frame_id = frame
        elif frame != self.frame_id:
            self.stats.skip("frame_id_mismatch")
            return None
        child = str(msg.child_frame_id)
        if p.child_frame_id and child != p.child_frame_id:
            self.stats.skip("child_frame_id_mismatch")
            return None
        t_ns = ros_msgs.stamp_ns(msg.header)
        if self.last_t_ns is not None:
            if t_ns < self.last_t_ns:
                self.stats.skip("time_backwards")
                return None
            if t_ns == self.last_t_ns:
                self.stats.skip("duplicate_stamp")
                return None
            gap = (t_ns - self.last_t_ns) * 1e-9
            if gap > p.max_gap_s:
                self.gaps += 1
                self.flagged = True
                self.last_gap_s = gap
                self.max_gap_seen_s = max(self.max_gap_seen_s, gap)
        T = make_T(quat_xyzw_to_matrix(q), t)
        if self._T_child_base is not None:
            T = T @ self._T_child_base
        cov: NDArray[np.float64] | None = np.asarray(msg.pose.covariance, dtype=np.float64).reshape(6, 6)
        assert cov is not None
        if not np.any(cov):
            cov = None
        elif not (np.all(np.isfinite(cov)) and np.allclose(cov, cov.T, atol=1e-9) and np.all(np.diag(cov) >= 0)):
            self.bad_covariance += 1
            cov = None
        self.last_t_ns = t_ns
        self.accepted += 1
        return Odometry(t_ns, T, cov, frame_id=frame, child_frame_id="base_link" if self._T_child_base is not None
                        else child)

    def report(self) -> dict[str, Any]:
        return {
            "received": self.stats.messages,
            "accepted": self.accepted,
            "skipped": dict(self.stats.skipped),
            "skipped_total": self.stats.total_skipped,
            "gaps": self.gaps,
            "last_gap_s": self.last_gap_s,
            "max_gap_seen_s": self.max_gap_seen_s,
            "flagged": self.flagged,
            "bad_covariance": self.bad_covariance,
            "frame_id": self.frame_id,
            "last_t_ns": self.last_t_ns,
        }


def encode_odometry(odom: Odometry, twist: NDArray[np.floating] | None = None) -> bytes:
    """`hw.messages.Odometry` -> nav_msgs/Odometry CDR bytes."""
    msg = ros_msgs.odometry_msg(odom.t_ns, odom.T_odom_base, odom.frame_id, odom.child_frame_id,
                                odom.covariance, twist)
    return ros_msgs.serialize(msg, ros_msgs.ODOMETRY)


class OdometryReceiver:
    """Subscribes to nav_msgs/Odometry CDR on a Zenoh session and feeds checked messages to `sink`.

    `session` is an open `zenoh.Session` (from `runtime.transport.bus.Bus.session`); the sink is called
    in Zenoh's callback thread and must not block (a `BoundedFifo.put`). A sink exception
    (e.g. the queue closed at shutdown) is counted in `sink_errors`, never raised into Zenoh.
    """

    def __init__(
        self, session: Any, key_expr: str, sink: Callable[[Odometry], None],
        params: OdometryCheckParams | None = None, clock: Callable[[], float] | None = None,
    ) -> None:
        import time

        self.key_expr = key_expr
        self.checker = OdometryChecker(params)
        self.sink = sink
        self.sink_errors = 0
        self.last_sink_error: str | None = None
        self._clock = clock or time.monotonic
        self.last_receive: float | None = None
        self._lock = threading.Lock()  # serialises the (rare) concurrent callbacks; uncontended
        self._sub = session.declare_subscriber(key_expr, self._on_sample)

    def _on_sample(self, sample: Any) -> None:
        payload = sample.payload.to_bytes()
        with self._lock:
            self.last_receive = self._clock()
            odom = self.checker.check_payload(payload)
        if odom is None:
            return
        try:
            self.sink(odom)
        except Exception as exc:
            self.sink_errors += 1
            self.last_sink_error = f"{type(exc).__name__}: {exc}"

    def report(self, stale_after_s: float = 1.0) -> dict[str, Any]:
        r = self.checker.report()
        age = None if self.last_receive is None else self._clock() - self.last_receive
        r.update(key_expr=self.key_expr, sink_errors=self.sink_errors, last_sink_error=self.last_sink_error,
                 seconds_since_last=age, stale=age is None or age > stale_after_s)
        return r

    def close(self) -> None:
        with contextlib.suppress(Exception):  # session already closed
            self._sub.undeclare()


class OdometrySender:
    """Publishes odometry as nav_msgs/Odometry CDR on a key expression (tests, the simulator).

    Odometry must not be lost, so the publisher blocks rather than drops when Zenoh's
    transmission queue is full (Zenoh's default for puts is to drop: a burst of 1000 messages
    to a receiver starved of CPU lost 13 % of them)."""

    def __init__(self, session: Any, key_expr: str) -> None:
        import zenoh

        self.key_expr = key_expr
        self._pub = session.declare_publisher(key_expr, congestion_control=zenoh.CongestionControl.BLOCK)
        self.sent = 0

    def wait_for_subscribers(self, timeout_s: float) -> bool:
        """Wait until a subscriber matches the key: Zenoh declarations propagate asynchronously
        and a put before that is silently dropped. True if one matched within `timeout_s`."""
        deadline = time.monotonic() + timeout_s
        while not self._pub.matching_status.matching:
            if time.monotonic() >= deadline:
                return False
            time.sleep(0.01)
        return True

    def send(self, odom: Odometry, twist: NDArray[np.floating] | None = None) -> None:
        self.send_raw(encode_odometry(odom, twist))

    def send_raw(self, payload: bytes) -> None:
        self._pub.put(payload)
        self.sent += 1

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self._pub.undeclare()
