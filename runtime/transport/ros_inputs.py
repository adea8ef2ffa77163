"""The runtime's ROS 2 inputs besides odometry: `/initialpose` (I/O shell around
`runtime.transport.ros_interface.parse_initial_pose`).

An accepted initial pose is handed to the `LocalizationCore` (`set_initial_pose`): the next
VLoc queries are global localization restricted to map keyframes near it. A message that does
not decode, names another frame than the map's, or holds NaN/inf is refused and counted by
reason, never applied; `report()` goes into the service status (`inputs.initial_pose`).
"""

from __future__ import annotations

import logging
import threading
from collections import Counter
from typing import Any, Protocol

from litevloc.config.schema import ZenohConfig
from litevloc.hw import ros_msgs
from litevloc.runtime.transport.ros_interface import InitialPose, InitialPoseRefused, parse_initial_pose

log = logging.getLogger(__name__)

INITIAL_POSE_TOPIC = "initialpose"


class InitialPoseSink(Protocol):
    def set_initial_pose(self, pose: InitialPose) -> None: ...


class InitialPoseInput:
    """Subscribes to `initialpose` on a `runtime.transport.bus.Bus` and feeds `sink` (the core)."""

    def __init__(self, bus: Any, sink: InitialPoseSink, cfg: ZenohConfig) -> None:
        self.sink, self.cfg = sink, cfg
        self.received = 0
        self.applied = 0
        self.refused: Counter[str] = Counter()
        self.last_refusal: str | None = None
        self.last_applied: dict[str, Any] | None = None
        self._lock = threading.Lock()
        self._sub = bus.subscribe_topic(INITIAL_POSE_TOPIC, ros_msgs.POSE_COV_STAMPED, self._on_sample)

    def handle(self, payload: bytes) -> InitialPose | None:
        """Decode, check and apply one message; the applied pose, or None (refused and counted)."""
        with self._lock:
            self.received += 1
            try:
                msg = ros_msgs.deserialize(payload, ros_msgs.POSE_COV_STAMPED)
                pose = parse_initial_pose(msg, self.cfg.tf.map_frame, self.cfg.initial_pose)
            except (ros_msgs.MessageDecodeError, InitialPoseRefused) as exc:
                kind = "undecodable" if isinstance(exc, ros_msgs.MessageDecodeError) else _reason_kind(str(exc))
                self.refused[kind] += 1
                self.last_refusal = str(exc)
                log.warning("initial pose refused: %s", exc)
                return None
            self.sink.set_initial_pose(pose)
            self.applied += 1
            x, y = (round(float(v), 3) for v in pose.T_map_base[:2, 3])
            self.last_applied = {"t_ns": pose.t_ns, "x": x, "y": y, "radius_m": round(pose.radius_m, 2)}
            return pose

    def _on_sample(self, sample: Any) -> None:
        self.handle(sample.payload.to_bytes())

    def report(self) -> dict[str, Any]:
        with self._lock:
            return {"received": self.received, "applied": self.applied, "refused": dict(self.refused),
                    "last_refusal": self.last_refusal, "last_applied": self.last_applied}

    def close(self) -> None:
        self._sub.undeclare()


def _reason_kind(text: str) -> str:
    """A short counter name for a refusal message."""
    for key, kind in (("frame_id", "wrong_frame"), ("NaN", "non_finite"), ("quaternion", "bad_quaternion"),
                      ("standard deviation", "too_uncertain")):
        if key in text:
            return kind
    return "bad_covariance"
