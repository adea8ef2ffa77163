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
  and acceptance, tracking state, map id with OK/WARN/ERROR levels (`runtime.service.diagnostics`),
  sent with the status tick at `diagnostics.period_s` (1 Hz) when the publisher has a
  `DiagnosticsPublisher`.

What is published, and when (tracking loss, INIT), is decided by the service's core
(`runtime.service.core`); the publisher here only serialises what it is given.

Every put carries an 8-byte attachment (little-endian uint64): the publisher's
`time.monotonic_ns()` at send time (CLOCK_MONOTONIC is machine-wide), so a subscriber on
the same machine measures wire latency (`attach_send_time: false` turns it off).
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import struct
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from litevloc.base.errors import LiteVLocError
from litevloc.config.schema import TfConfig, ZenohConfig
from litevloc.hw import ros_msgs
from litevloc.runtime.metrics import LatencyWindow, jsonable, now_ns
from litevloc.runtime.transport.rmw_zenoh import (
    Durability,
    History,
    NodeIdentity,
    Qos,
    Ros2Distro,
    attachment,
    attachment_fields,
    entity_gid,
    fully_qualified,
    resolve_distro,
    ros_namespace,
    topic_keyexpr,
)
from litevloc.runtime.transport.ros_interface import TF_MESSAGE, tf_message

log = logging.getLogger(__name__)

TOPICS: dict[str, tuple[str, str]] = {
    "pose": ("litevloc/pose", ros_msgs.ODOMETRY),
    "vloc": ("litevloc/vloc", ros_msgs.POSE_COV_STAMPED),
    "map_to_odom": ("litevloc/map_to_odom", ros_msgs.TRANSFORM_STAMPED),
    "status": ("litevloc/status", ros_msgs.STRING),
    "diagnostics": ("litevloc/diagnostics", ros_msgs.DIAGNOSTIC_ARRAY),
    "tf": ("tf", TF_MESSAGE),
}
# ROS 2 QoS of the topics whose QoS is not the default stream profile (`STREAM_QOS`): tf2's
# (tf2_ros DynamicBroadcasterQoS / StaticBroadcasterQoS)
STREAM_QOS = Qos(depth=10)
EVENT_QOS = Qos(history=History.KEEP_ALL)  # `reliable` publishers: every message is an event, none dropped
TOPIC_QOS: dict[str, Qos] = {"tf": Qos(depth=100), "tf_static": Qos(durability=Durability.TRANSIENT_LOCAL, depth=1)}


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
        TF_MESSAGE: tf_message([(0, eye, "map", "odom")]),
    }
    for typename, msg in msgs.items():
        ros_msgs.deserialize(ros_msgs.serialize(msg, typename), typename)


class BusError(LiteVLocError, RuntimeError):
    """The Zenoh session could not be opened or used; the message names the endpoint."""


def topic_key(namespace: str, topic: str) -> str:
    """Bridge naming: `("robot1", "pose")` -> `robot1/litevloc/pose`; topic may also be a ROS topic name."""
    base = TOPICS[topic][0] if topic in TOPICS else topic.lstrip("/")
    return f"{namespace.strip('/')}/{base}" if namespace.strip("/") else base


def _json5(value: Any) -> str:
    return value if isinstance(value, str) else json.dumps(value)


def zenoh_config(cfg: ZenohConfig, mode: str | None = None) -> Any:
    """A `zenoh.Config` with every relevant key set explicitly from `cfg`; `mode` overrides
    `cfg.mode` (the map service runs as a `"router"` by default)."""
    import zenoh

    c = zenoh.Config()
    try:
        c.insert_json5("mode", json.dumps(mode or cfg.mode))
        c.insert_json5("scouting/multicast/enabled", json.dumps(cfg.multicast_scouting))
        c.insert_json5("listen/endpoints", json.dumps([] if (mode or cfg.mode) == "client" else list(cfg.listen)))
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


def open_session(cfg: ZenohConfig, mode: str | None = None) -> Any:
    """Open a Zenoh session (`mode` overrides `cfg.mode`); BusError with the endpoints and
    Zenoh's reason on failure."""
    import zenoh

    conf = zenoh_config(cfg, mode)
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
    """A declared Zenoh publisher for one ROS type; counts puts and times them.

    `gid`: the publisher's rmw_zenoh GID; with one, every put carries rmw_zenoh's attachment
    (sequence number, source timestamp, GID) instead of the 8-byte send time. `cache`: an
    advanced publisher that keeps the last `cache` samples for late-joining subscribers (a
    TRANSIENT_LOCAL topic, as rmw_zenoh declares it)."""

    def __init__(self, session: Any, key_expr: str, typename: str, attach_send_time: bool = True,
                 reliable: bool = False, gid: bytes | None = None, cache: int = 0) -> None:
        import zenoh

        self.key_expr, self.typename = key_expr, typename
        self.attach_send_time = attach_send_time
        self.gid = gid
        self.seq = 0
        cc = zenoh.CongestionControl.BLOCK if reliable else zenoh.CongestionControl.DROP
        enc = zenoh.Encoding.APPLICATION_CDR.with_schema(typename)
        if cache > 0:
            import zenoh.ext

            # rmw_zenoh: a TRANSIENT_LOCAL publisher caches `depth` samples, is detectable by late
            # subscribers and (RELIABLE) sends sporadic heartbeats for sample-miss detection
            self._pub = zenoh.ext.declare_advanced_publisher(
                session, key_expr, encoding=enc, congestion_control=cc,
                cache=zenoh.ext.CacheConfig(cache), publisher_detection=True,
                sample_miss_detection=zenoh.ext.MissDetectionConfig(heartbeat=None, sporadic_heartbeat=0.5))
        else:
            self._pub = session.declare_publisher(key_expr, encoding=enc, congestion_control=cc)
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
            status = getattr(self._pub, "matching_status", None)
            if status is None:  # an advanced publisher: cannot tell
                return False
            if status.matching:
                return True
            if time.monotonic() >= deadline:
                return False
            time.sleep(0.01)

    def put_bytes(self, payload: bytes) -> None:
        t0 = now_ns()
        try:
            if self.gid is not None:
                self.seq += 1
                self._pub.put(payload, attachment=attachment(self.seq, time.time_ns(), self.gid))
            elif self.attach_send_time:
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
    """The publisher's monotonic send time from a sample's 8-byte attachment, if it has one."""
    att = sample.attachment
    if att is None:
        return None
    b = att.to_bytes()
    return struct.unpack("<Q", b)[0] if len(b) == 8 else None


def wire_latency_ns(sample: Any) -> int | None:
    """Send -> now (ns) of a sample: from the 8-byte monotonic send time, or from an rmw_zenoh
    attachment's source timestamp (system clock); None without either."""
    sent = send_time_ns(sample)
    if sent is not None:
        return now_ns() - sent
    att = sample.attachment
    fields = None if att is None else attachment_fields(att.to_bytes())
    return None if fields is None else time.time_ns() - fields[1]


class Subscription:
    """A Zenoh subscriber and, under rmw_zenoh, its liveliness token (both undeclared together)."""

    def __init__(self, sub: Any, token: Any = None) -> None:
        self._sub, self._token = sub, token

    def undeclare(self) -> None:
        for h in (self._token, self._sub):
            if h is not None:
                with contextlib.suppress(Exception):  # session already closed
                    h.undeclare()


def open_session_at(cfg: ZenohConfig, rt_priority: int) -> tuple[Any, str]:
    """`open_session` from a helper thread in SCHED_FIFO at `rt_priority` (0: the caller's
    policy), so the I/O threads Zenoh starts inherit it: at normal priority they wait for a
    core behind every other process before a put reaches the socket (wire p99 in tens of ms
    on a loaded 2-core machine). Returns (session, the policy in force, as text); without
    the privilege the session opens at normal priority and the reason is logged."""
    if rt_priority <= 0 or not hasattr(os, "SCHED_FIFO"):
        return open_session(cfg), "normal"
    out: dict[str, Any] = {}

    def body() -> None:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(rt_priority))  # this thread only
            out["why"] = f"SCHED_FIFO {rt_priority}"
        except OSError as exc:
            out["why"] = f"normal (SCHED_FIFO {rt_priority} not permitted: {exc.strerror})"
            log.warning("zenoh threads: %s", out["why"])
        try:
            out["session"] = open_session(cfg)
        except BaseException as exc:  # re-raised in the caller's thread
            out["error"] = exc

    t = threading.Thread(target=body, name="zenoh-open")
    t.start()
    t.join()
    if "error" in out:
        raise out["error"]
    return out["session"], str(out["why"])


class Bus:
    """One Zenoh session plus LiteVLoc's key naming: `zenoh.ros2` "bridge" (`<ns>/<topic>`) or
    "rmw_zenoh" (the session is one ROS 2 node `node_name`; see `runtime.transport.rmw_zenoh`).

    Topics are named as ROS topics relative to the namespace (`litevloc/pose`, `tf`), or by
    their short name in `TOPICS` (`pose`)."""

    def __init__(self, cfg: ZenohConfig, node_name: str | None = None, rt_priority: int = 0) -> None:
        self.cfg = cfg
        # checked before a session opens: `auto` with an unusable ROS_DISTRO fails here
        self.distro = resolve_distro(cfg.ros2_distro) if cfg.ros2 == "rmw_zenoh" else Ros2Distro.JAZZY
        # rt_priority: the session's I/O threads in SCHED_FIFO (`open_session_at`); `scheduling` says what holds
        self.session, self.scheduling = open_session_at(cfg, rt_priority)
        self._closed = False
        self.node: NodeIdentity | None = None
        self._tokens: list[Any] = []
        self._next_entity = 1
        if cfg.ros2 == "rmw_zenoh":
            self.node = NodeIdentity(cfg.domain_id, str(self.session.info.zid()), 0, ros_namespace(cfg.namespace),
                                     node_name or cfg.node_name, distro=self.distro)
            log.info("rmw_zenoh: node %s as ROS 2 %s names it", self.node.node_name, self.distro.value)
            self._tokens.append(self._declare_token(self.node.node_token()))

    @property
    def rmw_zenoh(self) -> bool:
        return self.node is not None

    def _declare_token(self, key: str) -> Any:
        try:
            return self.session.liveliness().declare_token(key)
        except Exception as exc:
            raise BusError(f"cannot declare the liveliness token {key!r}: {exc}") from exc

    def key(self, topic: str, typename: str | None = None) -> str:
        """The Zenoh key of a topic (its type is needed under rmw_zenoh: it is part of the key)."""
        name = TOPICS[topic][0] if topic in TOPICS else topic
        if self.node is None:
            return topic_key(self.cfg.namespace, name)
        tn = typename or TOPICS[topic][1]
        return topic_keyexpr(self.cfg.domain_id, fully_qualified(self.cfg.namespace, name), tn, self.distro)

    def _endpoint(self, kind: str, topic: str, typename: str, qos: Qos) -> tuple[Any, bytes]:
        """rmw_zenoh: declare the MP/MS liveliness token of a new endpoint; (token, GID)."""
        assert self.node is not None
        name = TOPICS[topic][0] if topic in TOPICS else topic
        key = self.node.endpoint_token(self._next_entity, kind, fully_qualified(self.cfg.namespace, name),
                                       typename, qos)
        self._next_entity += 1
        token = self._declare_token(key)
        self._tokens.append(token)
        return token, entity_gid(key)

    def publisher(self, topic: str, typename: str | None = None, reliable: bool = False,
                  qos: Qos | None = None) -> TopicPublisher:
        """A publisher on a namespaced topic. Streams (poses, subgoals) drop a message when the
        transport is congested (the next one supersedes it); `reliable` publishers (goals,
        cancels, planner status: each message is an event) block until it is queued instead
        (ROS 2 QoS KEEP_ALL, as rmw_zenoh maps it). `qos` overrides the topic's ROS 2 QoS."""
        tn = typename or TOPICS[topic][1]
        short = topic.rsplit("/", 1)[-1]
        q = qos or TOPIC_QOS.get(short) or (EVENT_QOS if reliable else STREAM_QOS)
        cache = q.depth if q.durability == Durability.TRANSIENT_LOCAL else 0
        if self.node is None:
            return TopicPublisher(self.session, self.key(topic, tn), tn, self.cfg.attach_send_time, reliable)
        _, gid = self._endpoint("MP", topic, tn, q)
        return TopicPublisher(self.session, self.key(topic, tn), tn, True, reliable or q.history == History.KEEP_ALL,
                              gid=gid, cache=cache)

    def subscribe_topic(self, topic: str, typename: str, callback: Callable[[Any], None],
                        qos: Qos = STREAM_QOS) -> Subscription:
        """Subscribe to a namespaced ROS topic of type `typename` (under rmw_zenoh with its MS token)."""
        sub = self.session.declare_subscriber(self.key(topic, typename), callback)
        if self.node is None:
            return Subscription(sub)
        token, _ = self._endpoint("MS", topic, typename, qos)
        return Subscription(sub, token)

    def announce_subscription(self, topic: str, typename: str, qos: Qos = STREAM_QOS) -> None:
        """rmw_zenoh: declare the MS token of a subscription made elsewhere on `key(topic, typename)`."""
        if self.node is not None:
            self._endpoint("MS", topic, typename, qos)

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
            for tok in reversed(self._tokens):
                with contextlib.suppress(Exception):  # session already closed
                    tok.undeclare()
            try:
                self.session.close()
            except Exception as exc:  # already closed
                log.debug("zenoh close: %s", exc)

    def __enter__(self) -> Bus:
        return self

    def __exit__(self, *_: Any) -> None:
        self.close()


class LiteVLocPublisher:
    """Serialises LiteVLoc's topics onto a `Bus`: each message as it is given (what to publish
    is the caller's decision, `runtime.service.core`).

    Frame names from `tf` (`zenoh.tf`, REP-105 defaults `map`, `odom`, `base_link`). With
    `tf.publish_tf`, every map->odom also goes out on `/tf` (tf2_msgs/TFMessage, stamped with the
    odometry stamp it was computed from plus `tf.post_date_s`); with `tf.camera_frame`, the camera
    mount `T_base_camera` on `/tf_static` once (cached for late subscribers under rmw_zenoh; with
    the bridge repeated with every status). Called from one thread (the service's publisher stage).
    """

    def __init__(
        self, bus: Bus, *, tf: TfConfig | None = None, diagnostics: Any = None,
        T_base_camera: NDArray[np.floating] | None = None,
    ) -> None:
        self.bus = bus
        self.tf = tf = tf or TfConfig()
        self.map_frame, self.odom_frame, self.base_frame = tf.map_frame, tf.odom_frame, tf.base_frame
        self.pubs = {name: bus.publisher(name) for name in TOPICS if name != "tf" or tf.publish_tf}
        self._static: Any = None
        if tf.camera_frame:
            if T_base_camera is None:
                raise ValueError("zenoh.tf.camera_frame is set but no T_base_camera was given")
            self._static = tf_message([(time.time_ns(), np.asarray(T_base_camera, np.float64), tf.base_frame,
                                        tf.camera_frame)])
            self.pubs["tf_static"] = bus.publisher("tf_static", TF_MESSAGE)
            self.pubs["tf_static"].put(self._static)
        warm_codecs()
        self.diagnostics = diagnostics  # runtime.service.diagnostics.DiagnosticsPublisher or None
        self.on_status: Callable[[dict[str, Any]], None] | None = None  # e.g. the live view's put_status

    def publish_pose(self, t_ns: int, T_map_base: NDArray[np.floating],
                     covariance: NDArray[np.floating] | None) -> None:
        """nav_msgs/Odometry on `pose`; covariance 6x6 in ROS order (None: zeros). Packed by
        `ros_msgs.odometry_cdr` (the bytes rosbags would give, without building the message)."""
        self.pubs["pose"].put_bytes(ros_msgs.odometry_cdr(t_ns, T_map_base, self.map_frame, self.base_frame,
                                                          covariance))

    def publish_map_to_odom(self, t_ns: int, T_map_odom: NDArray[np.floating]) -> None:
        """`map_to_odom` (TransformStamped) and, with `tf.publish_tf`, the same on `/tf`."""
        self.pubs["map_to_odom"].put(ros_msgs.transform_stamped_msg(t_ns, T_map_odom, self.map_frame,
                                                                    self.odom_frame))
        if "tf" in self.pubs:
            t_tf = t_ns + round(self.tf.post_date_s * 1e9)
            self.pubs["tf"].put(tf_message([(t_tf, np.asarray(T_map_odom), self.map_frame, self.odom_frame)]))

    def publish_vloc(self, t_ns: int, T_map_camera: NDArray[np.floating],
                     covariance: NDArray[np.floating] | None) -> None:
        self.pubs["vloc"].put(ros_msgs.pose_cov_stamped_msg(t_ns, T_map_camera, self.map_frame, covariance))

    def publish_status(self, status: dict[str, Any]) -> None:
        text = json.dumps(jsonable(status), sort_keys=True)
        self.pubs["status"].put(ros_msgs.typestore().types[ros_msgs.STRING](data=text))
        if self._static is not None and not self.bus.rmw_zenoh:  # no cache for late subscribers: repeat it
            self.pubs["tf_static"].put(self._static)
        if self.diagnostics is not None:
            msg = self.diagnostics.maybe_message(status, time.time_ns())
            if msg is not None:
                self.pubs["diagnostics"].put(msg)
        if self.on_status is not None:
            self.on_status(status)

    def status(self) -> dict[str, Any]:
        return {"topics": {n: p.status() for n, p in self.pubs.items()}, "connectivity": self.bus.connectivity(),
                "scheduling": getattr(self.bus, "scheduling", "normal")}

    def close(self) -> None:
        for p in self.pubs.values():
            p.undeclare()
