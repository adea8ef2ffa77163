"""The Zenoh bus: an explicitly configured session and LiteVLoc's published topics.

Session (`open_session`, `Bus`): built only from `config.schema.ZenohConfig`, never from
Zenoh's defaults (which listen on every interface and multicast-scout): mode peer or
client, the given `listen` / `connect` endpoints, multicast scouting off unless asked,
optional TLS / access-control / extra blocks passed through to Zenoh's JSON5 config.
An unreachable `connect` endpoint fails the start within `connect_timeout_s` with a
`BusError` naming the endpoint (`require_connect: true`, the default) or, with
`require_connect: false`, the session starts and `Bus.connectivity()` (in the status)
reports that nothing is connected. A listen endpoint already in use fails at once.

Topics (key expressions mirror ROS names without the leading slash, prefixed by the
configured namespace: `<ns>/litevloc/pose`), payloads CDR-encoded ROS 2 messages from
`hw.ros_msgs` (rosbags, with the 4-byte CDR encapsulation header), so a ROS 2 system
behind zenoh-bridge-ros2dds receives them unchanged; Zenoh encoding
`application/cdr;<ros type>`:

* `litevloc/pose` nav_msgs/Odometry: fused `T_map_base` (frame `map`, child `base_link`),
  pose covariance 6x6 in ROS order (x, y, z, rot x, rot y, rot z), twist zero.
* `litevloc/vloc` geometry_msgs/PoseWithCovarianceStamped: an accepted VLoc pose,
  `T_map_camera` of the camera optical frame (frame `map`), covariance of a right
  (camera-frame) perturbation, order (tx, ty, tz, rx, ry, rz), as `pipelines.pnp` gives it.
* `litevloc/map_to_odom` geometry_msgs/TransformStamped: `T_map_odom` (REP-105 correction).
* `litevloc/status` std_msgs/String: JSON (state, reasons, queue and stage metrics), ~1 Hz.
* `litevloc/diagnostics` diagnostic_msgs/DiagnosticArray: per-stage times, queues, VLoc rate
  and acceptance, tracking state, map id with OK/WARN/ERROR levels (`runtime.diagnostics`),
  sent with the status tick at `diagnostics.period_s` (1 Hz) when the publisher has a
  `DiagnosticsPublisher`.

Tracking loss (how the flag is carried, `RuntimeConfig.lost_policy`):
* `"flag"` (default): poses keep coming, but every diagonal entry of the pose
  covariance is raised to at least `lost_variance` (1e4 m^2 / rad^2 by default, so any
  covariance-aware consumer ignores them), and `litevloc/status` says `"state": "LOST"`
  with the reason. Frame ids are NOT changed (a renamed child frame would break TF users).
  `map_to_odom` is still published (its last good value).
* `"withhold"`: nothing is published on `pose` and `map_to_odom` while LOST; status goes on.
Before the first accepted VLoc update the map frame is undefined: no pose is published
under either policy (status state INIT).

Every put carries an 8-byte attachment (little-endian uint64): the publisher's
`time.monotonic_ns()` at send time (CLOCK_MONOTONIC is machine-wide), so a subscriber on
the same machine measures wire latency (`attach_send_time: false` turns it off).
"""

from __future__ import annotations

import contextlib
import json
import logging
import struct
import time
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from litevloc.base.errors import LiteVLocError
from litevloc.config.schema import ZenohConfig
from litevloc.hw import ros_msgs
from litevloc.runtime.metrics import LatencyWindow, jsonable, now_ns

log = logging.getLogger(__name__)

TOPICS: dict[str, tuple[str, str]] = {
    "pose": ("litevloc/pose", ros_msgs.ODOMETRY),
    "vloc": ("litevloc/vloc", ros_msgs.POSE_COV_STAMPED),
    "map_to_odom": ("litevloc/map_to_odom", ros_msgs.TRANSFORM_STAMPED),
    "status": ("litevloc/status", ros_msgs.STRING),
    "diagnostics": ("litevloc/diagnostics", ros_msgs.DIAGNOSTIC_ARRAY),
}


def warm_codecs() -> None:
    """Build, serialise and decode one message of each topic type once.

    rosbags generates its CDR (de)serialisers on first use (~0.2 s per type on the
    target); doing it at start-up keeps that stall off the first published pose.
    """
    eye = np.eye(4)
    msgs = {
        ros_msgs.ODOMETRY: ros_msgs.odometry_msg(0, eye, "map", "base_link"),
        ros_msgs.POSE_COV_STAMPED: ros_msgs.pose_cov_stamped_msg(0, eye, "map", None),
        ros_msgs.TRANSFORM_STAMPED: ros_msgs.transform_stamped_msg(0, eye, "map", "odom"),
        ros_msgs.STRING: ros_msgs.typestore().types[ros_msgs.STRING](data="{}"),
        ros_msgs.DIAGNOSTIC_ARRAY: ros_msgs.diagnostic_array_msg(0, [(0, "warm", "", "", [("k", "v")])]),
    }
    for typename, msg in msgs.items():
        ros_msgs.deserialize(ros_msgs.serialize(msg, typename), typename)


class BusError(LiteVLocError, RuntimeError):
    """The Zenoh session could not be opened or used; the message names the endpoint."""


def topic_key(namespace: str, topic: str) -> str:
    """`("robot1", "pose")` -> `robot1/litevloc/pose`; topic may also be a literal key."""
    base = TOPICS[topic][0] if topic in TOPICS else topic
    return f"{namespace.strip('/')}/{base}" if namespace.strip("/") else base


def _json5(value: Any) -> str:
    return value if isinstance(value, str) else json.dumps(value)


def zenoh_config(cfg: ZenohConfig) -> Any:
    """A `zenoh.Config` with every relevant key set explicitly from `cfg`."""
    import zenoh

    c = zenoh.Config()
    try:
        c.insert_json5("mode", json.dumps(cfg.mode))
        c.insert_json5("scouting/multicast/enabled", json.dumps(cfg.multicast_scouting))
        c.insert_json5("listen/endpoints", json.dumps([] if cfg.mode == "client" else list(cfg.listen)))
        c.insert_json5("connect/endpoints", json.dumps(list(cfg.connect)))
        c.insert_json5("connect/timeout_ms", str(int(cfg.connect_timeout_s * 1000)))
        c.insert_json5("connect/exit_on_failure", json.dumps(bool(cfg.require_connect and cfg.connect)))
        c.insert_json5("listen/exit_on_failure", "true")
        if cfg.tls is not None:
            c.insert_json5("transport/link/tls", _json5(cfg.tls))
        if cfg.access_control is not None:
            c.insert_json5("access_control", _json5(cfg.access_control))
        for key, value in (cfg.extra or {}).items():
            c.insert_json5(str(key), _json5(value))
    except Exception as exc:  # zenoh.ZError: a bad pass-through block
        raise BusError(f"invalid Zenoh configuration: {exc}") from exc
    return c


def open_session(cfg: ZenohConfig) -> Any:
    """Open a Zenoh session; BusError with the endpoints and Zenoh's reason on failure."""
    import zenoh

    conf = zenoh_config(cfg)
    try:
        return zenoh.open(conf)
    except Exception as exc:
        msg = str(exc).split(" at /")[0]  # drop Zenoh's Rust source location
        if "connect" in msg.lower():
            raise BusError(
                f"cannot reach Zenoh endpoint(s) {list(cfg.connect)} within {cfg.connect_timeout_s:g} s "
                f"(mode {cfg.mode}): {msg}. Is the peer/router running and the address right? "
                "(set zenoh.require_connect: false to start anyway and keep retrying)"
            ) from exc
        raise BusError(f"cannot open Zenoh session (listen {list(cfg.listen)}, connect {list(cfg.connect)}): "
                       f"{msg}") from exc


class TopicPublisher:
    """A declared Zenoh publisher for one ROS type; counts puts and times them."""

    def __init__(self, session: Any, key_expr: str, typename: str, attach_send_time: bool = True,
                 reliable: bool = False) -> None:
        import zenoh

        self.key_expr, self.typename = key_expr, typename
        self.attach_send_time = attach_send_time
        self._pub = session.declare_publisher(
            key_expr, encoding=zenoh.Encoding.APPLICATION_CDR.with_schema(typename),
            congestion_control=zenoh.CongestionControl.BLOCK if reliable else zenoh.CongestionControl.DROP,
        )
        self.sent = 0
        self.errors = 0
        self.last_error: str | None = None
        self.put_latency = LatencyWindow(1024)  # serialisation excluded: the Zenoh put only

    def put(self, msg: Any) -> None:
        self.put_bytes(ros_msgs.serialize(msg, self.typename))

    def wait_for_subscribers(self, timeout_s: float) -> bool:
        """Wait until at least one subscriber matches this key (Zenoh declarations propagate
        asynchronously: a put before that is silently dropped). True if one matched in time."""
        deadline = time.monotonic() + timeout_s
        while True:
            if self._pub.matching_status.matching:
                return True
            if time.monotonic() >= deadline:
                return False
            time.sleep(0.01)

    def put_bytes(self, payload: bytes) -> None:
        t0 = now_ns()
        try:
            if self.attach_send_time:
                self._pub.put(payload, attachment=struct.pack("<Q", now_ns()))
            else:
                self._pub.put(payload)
        except Exception as exc:
            self.errors += 1
            self.last_error = f"{type(exc).__name__}: {exc}"
            raise BusError(f"publishing on {self.key_expr} failed: {exc}") from exc
        self.put_latency.add_since(t0)
        self.sent += 1

    def undeclare(self) -> None:
        with contextlib.suppress(Exception):
            self._pub.undeclare()

    def status(self) -> dict[str, Any]:
        return {"key": self.key_expr, "sent": self.sent, "errors": self.errors, "last_error": self.last_error,
                "put_ms": self.put_latency.summary()}


def send_time_ns(sample: Any) -> int | None:
    """The publisher's monotonic send time from a sample's attachment, if it has one."""
    att = sample.attachment
    if att is None:
        return None
    b = att.to_bytes()
    return struct.unpack("<Q", b)[0] if len(b) == 8 else None


class Bus:
    """One Zenoh session plus LiteVLoc's key naming."""

    def __init__(self, cfg: ZenohConfig) -> None:
        self.cfg = cfg
        self.session = open_session(cfg)
        self._closed = False

    def key(self, topic: str) -> str:
        return topic_key(self.cfg.namespace, topic)

    def publisher(self, topic: str, typename: str | None = None, reliable: bool = False) -> TopicPublisher:
        """A publisher on a namespaced topic. Streams (poses, subgoals) drop a message when the
        transport is congested (the next one supersedes it); `reliable` publishers (goals,
        cancels, planner status: each message is an event) block until it is queued instead."""
        tn = typename or TOPICS[topic][1]
        return TopicPublisher(self.session, self.key(topic), tn, self.cfg.attach_send_time, reliable)

    def subscribe(self, key_expr: str, callback: Callable[[Any], None]) -> Any:
        """Declare a callback subscriber on a literal key expression (not namespaced)."""
        return self.session.declare_subscriber(key_expr, callback)

    def connectivity(self) -> dict[str, Any]:
        info = self.session.info
        peers = [str(z) for z in info.peers_zid()]
        routers = [str(z) for z in info.routers_zid()]
        out: dict[str, Any] = {"zid": str(info.zid()), "peers": peers, "routers": routers,
                               "connected": bool(peers or routers)}
        if self.cfg.connect and not out["connected"]:
            out["problem"] = f"no Zenoh peer/router connected (connect endpoints {list(self.cfg.connect)})"
        return out

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            try:
                self.session.close()
            except Exception as exc:  # already closed
                log.debug("zenoh close: %s", exc)

    def __enter__(self) -> Bus:
        return self

    def __exit__(self, *_: Any) -> None:
        self.close()


def gtsam_to_ros_covariance(cov: NDArray[np.floating]) -> NDArray[np.float64]:
    """6x6 covariance in GTSAM Pose3 order (rot, trans) -> ROS order (trans, rot)."""
    c = np.asarray(cov, dtype=np.float64).reshape(6, 6)
    p = [3, 4, 5, 0, 1, 2]
    return c[np.ix_(p, p)]


def flag_covariance(cov: NDArray[np.floating] | None, variance: float) -> NDArray[np.float64]:
    """Covariance with every diagonal entry raised to at least `variance` (the LOST flag)."""
    c = np.zeros((6, 6)) if cov is None else np.array(cov, dtype=np.float64).reshape(6, 6)
    d = np.arange(6)
    c[d, d] = np.maximum(np.nan_to_num(c[d, d], nan=variance), variance)
    return c


class LiteVLocPublisher:
    """Publishes LiteVLoc's topics on a `Bus`, applying the tracking-loss policy.

    Frame names: `map`, `odom`, `base_link` (REP-105). Called from one thread (the
    service's publisher stage).
    """

    def __init__(
        self, bus: Bus, lost_policy: str = "flag", lost_variance: float = 1.0e4,
        map_frame: str = "map", odom_frame: str = "odom", base_frame: str = "base_link",
        diagnostics: Any = None,
    ) -> None:
        if lost_policy not in ("flag", "withhold"):
            raise ValueError(f"lost_policy must be 'flag' or 'withhold', got {lost_policy!r}")
        self.bus = bus
        self.lost_policy, self.lost_variance = lost_policy, lost_variance
        self.map_frame, self.odom_frame, self.base_frame = map_frame, odom_frame, base_frame
        self.pubs = {name: bus.publisher(name) for name in TOPICS}
        warm_codecs()
        self.withheld = 0
        self.flagged = 0
        self.diagnostics = diagnostics  # runtime.diagnostics.DiagnosticsPublisher or None
        self.on_status: Callable[[dict[str, Any]], None] | None = None  # e.g. the live view's put_status

    def _lost_gate(self, lost: bool) -> bool:
        """True if the message may go out; counts flagged/withheld messages."""
        if not lost:
            return True
        if self.lost_policy == "withhold":
            self.withheld += 1
            return False
        self.flagged += 1
        return True

    def publish_pose(self, t_ns: int, T_map_base: NDArray[np.floating], covariance: NDArray[np.floating] | None,
                     lost: bool = False) -> bool:
        """nav_msgs/Odometry on `pose`; covariance in ROS order. False if withheld."""
        if not self._lost_gate(lost):
            return False
        cov = flag_covariance(covariance, self.lost_variance) if lost else covariance
        msg = ros_msgs.odometry_msg(t_ns, T_map_base, self.map_frame, self.base_frame, cov)
        self.pubs["pose"].put(msg)
        return True

    def publish_map_to_odom(self, t_ns: int, T_map_odom: NDArray[np.floating], lost: bool = False) -> bool:
        if lost and self.lost_policy == "withhold":
            return False
        self.pubs["map_to_odom"].put(ros_msgs.transform_stamped_msg(t_ns, T_map_odom, self.map_frame,
                                                                    self.odom_frame))
        return True

    def publish_vloc(self, t_ns: int, T_map_camera: NDArray[np.floating],
                     covariance: NDArray[np.floating] | None) -> None:
        self.pubs["vloc"].put(ros_msgs.pose_cov_stamped_msg(t_ns, T_map_camera, self.map_frame, covariance))

    def publish_status(self, status: dict[str, Any]) -> None:
        text = json.dumps(jsonable(status), sort_keys=True)
        self.pubs["status"].put(ros_msgs.typestore().types[ros_msgs.STRING](data=text))
        if self.diagnostics is not None:
            msg = self.diagnostics.maybe_message(status, time.time_ns())
            if msg is not None:
                self.pubs["diagnostics"].put(msg)
        if self.on_status is not None:
            self.on_status(status)

    def status(self) -> dict[str, Any]:
        return {"topics": {n: p.status() for n, p in self.pubs.items()}, "withheld": self.withheld,
                "flagged": self.flagged, "connectivity": self.bus.connectivity()}

    def close(self) -> None:
        for p in self.pubs.values():
            p.undeclare()
