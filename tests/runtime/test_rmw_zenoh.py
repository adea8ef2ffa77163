"""`zenoh.ros2: rmw_zenoh`: what LiteVLoc puts on Zenoh, read as an rmw_zenoh node would (keys,
liveliness tokens and attachments parsed by `tests/runtime/rmw_zenoh_reference.py`, written from
rmw_zenoh's design document; type hashes compared with ROS 2's own; payloads decoded by rosbags)."""

from __future__ import annotations

import threading
import time
from typing import Any

import numpy as np
import pytest

from litevloc.base.geometry import make_T, so3_exp
from litevloc.config.schema import TfConfig, ZenohConfig
from litevloc.hw import ros_msgs
from litevloc.runtime.transport import rmw_zenoh
from litevloc.runtime.transport.bus import Bus, LiteVLocPublisher
from litevloc.runtime.transport.ros_interface import TF_MESSAGE
from tests.runtime.rmw_zenoh_reference import (
    DOC_NODE_TOKEN,
    DOC_PUB_TOKEN,
    DOC_TOPIC_KEY,
    REFERENCE_HASHES,
    parse_attachment,
    parse_data_key,
    parse_token,
)
from tests.runtime.zenoh_helpers import free_port


@pytest.mark.parametrize("typename", sorted(REFERENCE_HASHES))
def test_type_hashes_equal_the_ones_ros2_generates(typename: str) -> None:
    assert rmw_zenoh.type_hash(typename) == REFERENCE_HASHES[typename]


def test_encoder_reproduces_the_design_document_examples() -> None:
    assert rmw_zenoh.topic_keyexpr(0, "/robot1/chatter", "std_msgs/msg/String") == DOC_TOPIC_KEY
    listener = rmw_zenoh.NodeIdentity(2, "aac3178e146ba6f1fc6e6a4085e77f21", 0, "/", "listener")
    assert listener.node_token() == DOC_NODE_TOKEN
    talker = rmw_zenoh.NodeIdentity(2, "8b20917502ee955ac4476e0266340d5c", 0, "/", "talker")
    assert talker.endpoint_token(10, "MP", "/chatter", "std_msgs/msg/String", rmw_zenoh.Qos(depth=7)) == DOC_PUB_TOKEN
    # and the independent reader agrees with the document
    t = parse_token(DOC_PUB_TOKEN)
    assert (t.kind, t.namespace, t.topic, t.type, t.qos.depth if t.qos else None) == (
        "MP", "/", "/chatter", "std_msgs/msg/String", 7)


def test_qos_and_attachment_layout() -> None:
    tl = rmw_zenoh.Qos(durability=rmw_zenoh.Durability.TRANSIENT_LOCAL, depth=1)
    assert rmw_zenoh.qos_keyexpr(tl) == ":1:,1:,:,:,,"
    ka = rmw_zenoh.Qos(reliability=rmw_zenoh.Reliability.BEST_EFFORT, history=rmw_zenoh.History.KEEP_ALL,
                       depth=42)
    assert rmw_zenoh.qos_keyexpr(ka) == "2::2,:,:,:,,"
    gid = bytes(range(16))
    att = rmw_zenoh.attachment(7, 1_700_000_000_123_456_789, gid)
    assert parse_attachment(att) == (7, 1_700_000_000_123_456_789, gid)
    assert rmw_zenoh.attachment_fields(att) == (7, 1_700_000_000_123_456_789, gid)
    assert rmw_zenoh.fully_qualified("robot1", "tf") == "/robot1/tf" and rmw_zenoh.fully_qualified("", "tf") == "/tf"


def _cfg(port: int, **kw: Any) -> ZenohConfig:
    return ZenohConfig(listen=(f"tcp/127.0.0.1:{port}",), ros2="rmw_zenoh", **kw)


class RosNodeView:
    """A plain Zenoh session doing what an rmw_zenoh subscriber does: graph from liveliness tokens,
    data from `<domain>/<topic>/<type>/<hash>` keys built from the reference tables."""

    def __init__(self, port: int) -> None:
        import zenoh

        conf = zenoh.Config()
        conf.insert_json5("mode", '"peer"')
        conf.insert_json5("connect/endpoints", f'["tcp/127.0.0.1:{port}"]')
        conf.insert_json5("listen/endpoints", "[]")
        conf.insert_json5("scouting/multicast/enabled", "false")
        self.session = zenoh.open(conf)
        self.samples: dict[str, list[tuple[bytes, bytes]]] = {}
        self.lock = threading.Lock()
        self.subs: list[Any] = []

    def subscribe(self, domain: int, fq_topic: str, typename: str) -> str:
        dds = "{}::msg::dds_::{}_".format(*typename.split("/msg/"))
        return self.subscribe_key(f"{domain}/{fq_topic.strip('/')}/{dds}/{REFERENCE_HASHES[typename]}")

    def subscribe_key(self, key: str) -> str:
        """Subscribe on a literal data key (another distribution's form)."""
        self.samples[key] = []

        def cb(sample: Any, key: str = key) -> None:
            att = sample.attachment
            with self.lock:
                self.samples[key].append((sample.payload.to_bytes(), b"" if att is None else att.to_bytes()))

        self.subs.append(self.session.declare_subscriber(key, cb))
        return key

    def tokens(self, domain: int) -> list[str]:
        return [str(r.ok.key_expr) for r in self.session.liveliness().get(f"@ros2_lv/{domain}/**", timeout=2.0)
                if r.ok is not None]

    def wait(self, key: str, n: int, timeout: float = 5.0) -> list[tuple[bytes, bytes]]:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            with self.lock:
                if len(self.samples[key]) >= n:
                    return list(self.samples[key])
            time.sleep(0.01)
        raise AssertionError(f"{len(self.samples[key])} of {n} samples on {key}")

    def close(self) -> None:
        self.session.close()


def publish_three_poses_and_tf(pub: LiteVLocPublisher, view: RosNodeView, k_pose: str,
                               k_tf: str) -> tuple[np.ndarray, list[tuple[bytes, bytes]]]:
    """Once `view` is matched on both keys: three poses (stamps 1 s + i ns) and one map -> odom;
    (the pose T_map_base, the three pose samples as `view` got them)."""
    for p in pub.pubs.values():
        if p.key_expr in (k_pose, k_tf):
            assert p.wait_for_subscribers(5.0), p.key_expr
    T = make_T(so3_exp(np.array([0.0, 0.0, 0.4])), np.array([1.0, 2.0, 0.0]))
    for i in range(3):
        pub.publish_pose(1_000_000_000 + i, T, np.eye(6) * 0.01)
    pub.publish_map_to_odom(5_000_000_000, T)
    return T, view.wait(k_pose, 3)


@pytest.mark.timeout(30)
def test_runtime_topics_as_an_rmw_zenoh_node_sees_them() -> None:
    port = free_port()
    T_bc = make_T(so3_exp(np.array([-1.2, 0.0, -1.57])), np.array([0.2, 0.0, 0.5]))
    with Bus(_cfg(port, domain_id=7, namespace="robot1", node_name="localizer")) as bus:
        pub = LiteVLocPublisher(bus, tf=TfConfig(camera_frame="camera_optical"), T_base_camera=T_bc)
        view = RosNodeView(port)
        try:
            k_pose = view.subscribe(7, "/robot1/litevloc/pose", ros_msgs.ODOMETRY)
            k_tf = view.subscribe(7, "/robot1/tf", TF_MESSAGE)
            T, got = publish_three_poses_and_tf(pub, view, k_pose, k_tf)
            seqs = []
            for payload, att in got:
                seq, ts, gid = parse_attachment(att)
                seqs.append(seq)
                assert abs(ts - time.time_ns()) < 5e9 and len(gid) == 16
                t_ns, T_rx, _ = ros_msgs.odometry_to_matrix(ros_msgs.deserialize(payload, ros_msgs.ODOMETRY))
                assert np.allclose(T_rx, T) and t_ns >= 1_000_000_000
            assert seqs == [1, 2, 3]  # from 1, one per sample of this publisher
            tf_payload, tf_att = view.wait(k_tf, 1)[0]
            msg = ros_msgs.deserialize(tf_payload, TF_MESSAGE)
            (ts_msg,) = msg.transforms
            assert (ts_msg.header.frame_id, ts_msg.child_frame_id) == ("map", "odom")
            assert parse_attachment(tf_att)[2] != parse_attachment(got[0][1])[2]  # one GID per publisher

            tokens = [parse_token(k) for k in view.tokens(7)]
            zid = str(bus.session.info.zid())
            nodes = [t for t in tokens if t.kind == "NN"]
            assert [(t.node_name, t.namespace, t.zid, t.enclave) for t in nodes] == [("localizer", "/robot1", zid, "/")]
            pubs = {t.topic: t for t in tokens if t.kind == "MP"}
            assert set(pubs) == {"/robot1/litevloc/pose", "/robot1/litevloc/vloc", "/robot1/litevloc/map_to_odom",
                                 "/robot1/litevloc/status", "/robot1/litevloc/diagnostics", "/robot1/tf",
                                 "/robot1/tf_static"}
            for topic, t in pubs.items():
                assert t.node_id == nodes[0].node_id and t.entity_id != t.node_id
                assert t.type_hash == REFERENCE_HASHES[t.type or ""], topic
            assert pubs["/robot1/tf"].qos is not None and pubs["/robot1/tf"].qos.depth == 100
            assert pubs["/robot1/tf_static"].qos == parse_token(
                "@ros2_lv/0/z/0/1/MP/%/%/n/%t/std_msgs::msg::dds_::String_/" + REFERENCE_HASHES["std_msgs/msg/String"]
                + "/:1:,1:,:,:,,").qos  # RELIABLE, TRANSIENT_LOCAL, KEEP_LAST 1: tf2's static QoS
            assert len({t.entity_id for t in pubs.values()}) == len(pubs)
        finally:
            view.close()
            pub.close()


@pytest.mark.timeout(30)
def test_tf_static_reaches_a_late_transient_local_subscriber() -> None:
    """rmw_zenoh's TRANSIENT_LOCAL subscription: an advanced subscriber querying late publishers' caches."""
    import zenoh.ext

    port = free_port()
    T_bc = make_T(so3_exp(np.array([0.1, 0.2, 0.3])), np.array([0.2, 0.0, 0.5]))
    with Bus(_cfg(port)) as bus:
        pub = LiteVLocPublisher(bus, tf=TfConfig(camera_frame="cam"), T_base_camera=T_bc)
        time.sleep(0.3)  # published long before anyone subscribes
        view = RosNodeView(port)
        got: list[bytes] = []
        key = "0/tf_static/tf2_msgs::msg::dds_::TFMessage_/" + REFERENCE_HASHES[TF_MESSAGE]
        try:
            sub = zenoh.ext.declare_advanced_subscriber(
                view.session, key, lambda s: got.append(s.payload.to_bytes()),
                history=zenoh.ext.HistoryConfig(detect_late_publishers=True, max_samples=1), subscriber_detection=True)
            deadline = time.monotonic() + 5
            while not got and time.monotonic() < deadline:
                time.sleep(0.02)
            assert got, "no cached /tf_static sample"
            (tr,) = ros_msgs.deserialize(got[0], TF_MESSAGE).transforms
            assert (tr.header.frame_id, tr.child_frame_id) == ("base_link", "cam")
            q = tr.transform.rotation
            T = make_T(np.eye(3), np.array([tr.transform.translation.x, tr.transform.translation.y,
                                            tr.transform.translation.z]))
            assert np.allclose(T[:3, 3], T_bc[:3, 3]) and abs(q.w ** 2 + q.x ** 2 + q.y ** 2 + q.z ** 2 - 1) < 1e-9
            sub.undeclare()
        finally:
            view.close()
            pub.close()


def test_bridge_mode_keeps_todays_keys() -> None:
    port = free_port()
    with Bus(ZenohConfig(listen=(f"tcp/127.0.0.1:{port}",), namespace="r1")) as bus:
        assert bus.key("pose") == "r1/litevloc/pose" and bus.key("tf") == "r1/tf" and not bus.rmw_zenoh
        assert bus.key("initialpose", ros_msgs.POSE_COV_STAMPED) == "r1/initialpose"
        assert parse_data_key(rmw_zenoh.topic_keyexpr(0, "/r1/initialpose", ros_msgs.POSE_COV_STAMPED)).topic == \
            "/r1/initialpose"
