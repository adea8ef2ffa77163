"""`zenoh.ros2_distro: humble`: LiteVLoc's keys and liveliness tokens as ROS 2 Humble's rmw_zenoh
writes them (`TypeHashNotSupported` where Jazzy's carry the RIHS01 hash), checked against literal
strings and the independent reader `tests/runtime/rmw_zenoh_reference.py`; a plain Zenoh session on
Humble's keys receives /tf and the pose, and Jazzy's keys then receive nothing."""

from __future__ import annotations

import threading
import time
from typing import Any

import numpy as np
import pytest

from litevloc.base.errors import LiteVLocError
from litevloc.base.loader import ConfigError, from_mapping
from litevloc.config.schema import TfConfig, ZenohConfig
from litevloc.hw import ros_msgs
from litevloc.runtime.transport import rmw_zenoh
from litevloc.runtime.transport.bus import Bus, LiteVLocPublisher
from litevloc.runtime.transport.rmw_zenoh import Ros2Distro
from litevloc.runtime.transport.ros_interface import TF_MESSAGE
from tests.runtime.rmw_zenoh_reference import (
    HUMBLE_TYPE_HASH,
    REFERENCE_HASHES,
    parse_attachment,
    parse_data_key,
    parse_token,
)
from tests.runtime.test_rmw_zenoh import RosNodeView, publish_three_poses_and_tf
from tests.runtime.zenoh_helpers import free_port

ZID = "8b20917502ee955ac4476e0266340d5c"
# what a Humble node subscribes on for LiteVLoc's /tf and pose (domain 7, namespace robot1)
HUMBLE_TF_KEY = "7/robot1/tf/tf2_msgs::msg::dds_::TFMessage_/TypeHashNotSupported"
HUMBLE_POSE_KEY = "7/robot1/litevloc/pose/nav_msgs::msg::dds_::Odometry_/TypeHashNotSupported"
HUMBLE_ODOM_KEY = "7/robot1/odom/nav_msgs::msg::dds_::Odometry_/TypeHashNotSupported"
HUMBLE_TF_TOKEN = (f"@ros2_lv/7/{ZID}/0/3/MP/%/%robot1/localizer/%robot1%tf/tf2_msgs::msg::dds_::TFMessage_/"
                   "TypeHashNotSupported/::,100:,:,:,,")
HUMBLE_POSE_TOKEN = (f"@ros2_lv/7/{ZID}/0/1/MP/%/%robot1/localizer/%robot1%litevloc%pose/"
                     "nav_msgs::msg::dds_::Odometry_/TypeHashNotSupported/::,10:,:,:,,")


def _node(distro: Ros2Distro) -> rmw_zenoh.NodeIdentity:
    return rmw_zenoh.NodeIdentity(7, ZID, 0, "/robot1", "localizer", distro=distro)


def test_humble_data_keys_and_tokens_are_humbles_literal_forms() -> None:
    h = Ros2Distro.HUMBLE
    assert rmw_zenoh.topic_keyexpr(7, "/robot1/tf", TF_MESSAGE, h) == HUMBLE_TF_KEY
    assert rmw_zenoh.topic_keyexpr(7, "/robot1/litevloc/pose", ros_msgs.ODOMETRY, h) == HUMBLE_POSE_KEY
    assert _node(h).endpoint_token(3, "MP", "/robot1/tf", TF_MESSAGE, rmw_zenoh.Qos(depth=100)) == HUMBLE_TF_TOKEN
    assert _node(h).endpoint_token(1, "MP", "/robot1/litevloc/pose", ros_msgs.ODOMETRY,
                                   rmw_zenoh.Qos()) == HUMBLE_POSE_TOKEN
    # the node token has no type: the same in both distributions
    assert _node(h).node_token() == _node(Ros2Distro.JAZZY).node_token() == \
        f"@ros2_lv/7/{ZID}/0/0/NN/%/%robot1/localizer"


def test_the_reader_splits_humble_tokens_field_by_field() -> None:
    t = parse_token(HUMBLE_TF_TOKEN, "humble")
    assert (t.domain_id, t.zid, t.node_id, t.entity_id, t.kind) == (7, ZID, 0, 3, "MP")
    assert (t.enclave, t.namespace, t.node_name) == ("/", "/robot1", "localizer")
    assert (t.topic, t.type, t.type_hash) == ("/robot1/tf", TF_MESSAGE, HUMBLE_TYPE_HASH)
    assert t.qos is not None and (t.qos.reliability, t.qos.durability, t.qos.history, t.qos.depth) == (1, 2, 1, 100)
    k = parse_data_key(HUMBLE_POSE_KEY, "humble")
    assert (k.domain_id, k.topic, k.type, k.type_hash) == (7, "/robot1/litevloc/pose", ros_msgs.ODOMETRY,
                                                          HUMBLE_TYPE_HASH)
    # a reader of one distribution refuses the other's hash chunk
    with pytest.raises(AssertionError):
        parse_token(HUMBLE_TF_TOKEN, "jazzy")
    jazzy_tf = rmw_zenoh.topic_keyexpr(7, "/robot1/tf", TF_MESSAGE, Ros2Distro.JAZZY)
    with pytest.raises(AssertionError):
        parse_data_key(jazzy_tf, "humble")


@pytest.mark.parametrize("typename", sorted(REFERENCE_HASHES))
def test_the_distributions_differ_in_the_type_hash_chunk_only(typename: str) -> None:
    qos = rmw_zenoh.Qos(durability=rmw_zenoh.Durability.TRANSIENT_LOCAL, depth=1)
    jazzy = _node(Ros2Distro.JAZZY).endpoint_token(5, "MS", "/robot1/x", typename, qos).split("/")
    humble = _node(Ros2Distro.HUMBLE).endpoint_token(5, "MS", "/robot1/x", typename, qos).split("/")
    assert (jazzy[11], humble[11]) == (REFERENCE_HASHES[typename], HUMBLE_TYPE_HASH)
    assert jazzy[:11] + jazzy[12:] == humble[:11] + humble[12:]
    kj = rmw_zenoh.topic_keyexpr(0, "/x", typename, Ros2Distro.JAZZY).split("/")
    kh = rmw_zenoh.topic_keyexpr(0, "/x", typename, Ros2Distro.HUMBLE).split("/")
    assert kj[:-1] == kh[:-1] and (kj[-1], kh[-1]) == (REFERENCE_HASHES[typename], HUMBLE_TYPE_HASH)


def test_payloads_are_the_same_cdr_in_both_distributions() -> None:
    """LiteVLoc encodes with Humble's message definitions; Jazzy's are the same for its types."""
    from rosbags.typesys import Stores, get_typestore

    humble, jazzy = get_typestore(Stores.ROS2_HUMBLE), get_typestore(Stores.ROS2_JAZZY)
    for t in REFERENCE_HASHES:
        assert humble.generate_msgdef(t, ros_version=2) == jazzy.generate_msgdef(t, ros_version=2), t


def test_the_setting_and_auto_detection() -> None:
    assert ZenohConfig().ros2_distro == "jazzy"
    with pytest.raises(ConfigError, match="ros2_distro"):
        from_mapping(ZenohConfig, {"ros2_distro": "iron"})
    assert rmw_zenoh.resolve_distro("humble", {}) is Ros2Distro.HUMBLE
    assert rmw_zenoh.resolve_distro("jazzy", {"ROS_DISTRO": "humble"}) is Ros2Distro.JAZZY  # explicit wins
    assert rmw_zenoh.resolve_distro("auto", {"ROS_DISTRO": "humble"}) is Ros2Distro.HUMBLE
    assert rmw_zenoh.resolve_distro("auto", {"ROS_DISTRO": "jazzy\n"}) is Ros2Distro.JAZZY
    for env in ({}, {"ROS_DISTRO": ""}, {"ROS_DISTRO": "iron"}):
        with pytest.raises(rmw_zenoh.Ros2DistroError, match=r"zenoh\.ros2_distro") as exc:
            rmw_zenoh.resolve_distro("auto", env)
        assert isinstance(exc.value, LiteVLocError)


def test_auto_reads_ros_distro_and_a_bad_one_fails_before_a_session_opens(monkeypatch: pytest.MonkeyPatch) -> None:
    port = free_port()
    cfg = ZenohConfig(listen=(f"tcp/127.0.0.1:{port}",), ros2="rmw_zenoh", ros2_distro="auto", namespace="robot1",
                      domain_id=7)
    monkeypatch.setenv("ROS_DISTRO", "humble")
    with Bus(cfg) as bus:
        assert bus.distro is Ros2Distro.HUMBLE and bus.key("tf", TF_MESSAGE) == HUMBLE_TF_KEY
    monkeypatch.setenv("ROS_DISTRO", "rolling")
    with pytest.raises(rmw_zenoh.Ros2DistroError, match="rolling"):
        Bus(cfg)
    # the bridge has no distribution: `auto` is not read there
    with Bus(ZenohConfig(listen=(f"tcp/127.0.0.1:{port}",), ros2_distro="auto")) as bus:
        assert bus.key("tf") == "tf"


@pytest.mark.timeout(30)
def test_a_humble_node_sees_tf_the_pose_and_the_tokens_and_reaches_the_odometry_input() -> None:
    port = free_port()
    cfg = ZenohConfig(listen=(f"tcp/127.0.0.1:{port}",), ros2="rmw_zenoh", ros2_distro="humble", domain_id=7,
                      namespace="robot1", node_name="localizer")
    with Bus(cfg) as bus:
        odom_rx: list[bytes] = []
        odom_got = threading.Event()

        def on_odom(sample: Any) -> None:
            odom_rx.append(sample.payload.to_bytes())
            odom_got.set()

        odom_sub = bus.subscribe_topic("odom", ros_msgs.ODOMETRY, on_odom)
        pub = LiteVLocPublisher(bus, tf=TfConfig(camera_frame="camera_optical"), T_base_camera=np.eye(4))
        view = RosNodeView(port)
        try:
            k_pose, k_tf = view.subscribe_key(HUMBLE_POSE_KEY), view.subscribe_key(HUMBLE_TF_KEY)
            jazzy_pose = view.subscribe(7, "/robot1/litevloc/pose", ros_msgs.ODOMETRY)  # a Jazzy node's key
            T, got = publish_three_poses_and_tf(pub, view, k_pose, k_tf)
            assert [parse_attachment(att)[0] for _, att in got] == [1, 2, 3]
            for payload, _ in got:
                assert np.allclose(ros_msgs.odometry_to_matrix(ros_msgs.deserialize(payload, ros_msgs.ODOMETRY))[1], T)
            (tr,) = ros_msgs.deserialize(view.wait(k_tf, 1)[0][0], TF_MESSAGE).transforms
            assert (tr.header.frame_id, tr.child_frame_id) == ("map", "odom")
            assert view.samples[jazzy_pose] == []  # Jazzy's key is another key: nothing arrives there

            tokens = [parse_token(k, "humble") for k in view.tokens(7)]  # every MP/MS hash chunk Humble's
            zid = str(bus.session.info.zid())
            assert [(t.node_name, t.namespace, t.zid) for t in tokens if t.kind == "NN"] == [
                ("localizer", "/robot1", zid)]
            pubs = {t.topic: t for t in tokens if t.kind == "MP"}
            assert {"/robot1/tf", "/robot1/tf_static", "/robot1/litevloc/pose"} <= set(pubs)
            assert (pubs["/robot1/tf"].type, pubs["/robot1/litevloc/pose"].type) == (TF_MESSAGE, ros_msgs.ODOMETRY)
            (sub,) = [t for t in tokens if t.kind == "MS"]
            assert (sub.topic, sub.type, sub.type_hash) == ("/robot1/odom", ros_msgs.ODOMETRY, HUMBLE_TYPE_HASH)

            # a Humble odometry publisher's key reaches LiteVLoc's subscription
            deadline = time.monotonic() + 5
            while not odom_got.is_set() and time.monotonic() < deadline:
                view.session.put(HUMBLE_ODOM_KEY, got[0][0])
                odom_got.wait(0.1)
            assert odom_rx and odom_rx[0] == got[0][0]
        finally:
            odom_sub.undeclare()
            view.close()
            pub.close()
