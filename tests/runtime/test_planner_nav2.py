"""Goals for Nav2 (`zenoh.goal_pose`) and goal images as sensor_msgs/Image."""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import pytest

from litevloc.config.schema import ZenohConfig
from litevloc.hw import ros_msgs
from litevloc.runtime.planner.node import KEYS, PlannerService
from litevloc.runtime.transport.bus import Bus
from litevloc.runtime.transport.ros_interface import image_to_rgb
from tests.runtime.rmw_zenoh_reference import REFERENCE_HASHES, parse_attachment
from tests.runtime.test_planner_service import img, planner, pose
from tests.runtime.test_rmw_zenoh import RosNodeView
from tests.runtime.zenoh_helpers import free_port


class _Recorder:
    def __init__(self) -> None:
        self.msgs: list[Any] = []

    def put(self, msg: Any) -> None:
        self.msgs.append(msg)

    def undeclare(self) -> None:
        pass


class _FakeBus:
    def __init__(self) -> None:
        self.pubs: dict[str, _Recorder] = {}

    def publisher(self, topic: str, *_: Any, **__: Any) -> _Recorder:
        return self.pubs.setdefault(topic, _Recorder())

    def subscribe_topic(self, *_: Any, **__: Any) -> Any:
        return None


def _xy(msg: Any) -> tuple[float, float]:
    return round(float(msg.pose.position.x), 3), round(float(msg.pose.position.y), 3)


def test_goal_mode_sends_the_goal_place_once_per_goal() -> None:
    goal_place = np.eye(4)
    goal_place[:3, 3] = [3.4, 0.5, 0.0]
    bus = _FakeBus()
    svc = PlannerService(bus, planner({7: 3, 8: 1}, {7: goal_place}), goal_pose="goal")
    svc.handle("pose", (5, pose(0.0)))
    svc.handle("goal", ("far", img(7)))
    for k, x in enumerate((0.2, 0.5, 1.0, 1.5)):
        svc.handle("pose", (10 + k, pose(x)))
    sent = bus.pubs[KEYS["goal_pose"]].msgs
    assert len(sent) == 1 and sent[0].header.frame_id == "map"
    assert _xy(sent[0])[0] == pytest.approx(3.4, abs=0.01)  # the goal image's place, not a path node
    svc.handle("goal", ("near", img(8)))  # queued behind "far": sent when it becomes active
    assert len(bus.pubs[KEYS["goal_pose"]].msgs) == 1


def test_image_goal_decoding() -> None:
    rgb = np.random.default_rng(0).integers(0, 255, (20, 24, 3), dtype=np.uint8)
    for enc, data in (("rgb8", rgb), ("bgr8", rgb[:, :, ::-1]), ("mono8", rgb[:, :, :1])):
        d = np.ascontiguousarray(data)
        msg = ros_msgs.typestore().types[ros_msgs.IMAGE](
            header=ros_msgs.header(0, "g"), height=20, width=24, encoding=enc, is_bigendian=0,
            step=24 * d.shape[2], data=d.reshape(-1))
        out = image_to_rgb(msg)
        assert out.shape == (20, 24, 3)
        assert np.array_equal(out, rgb if enc != "mono8" else np.repeat(rgb[:, :, :1], 3, axis=2))
    msg.encoding = "32FC1"
    with pytest.raises(ValueError, match="encoding"):
        image_to_rgb(msg)


@pytest.mark.timeout(30)
def test_subgoals_to_nav2_over_rmw_zenoh_from_a_raw_image_goal() -> None:
    port = free_port()
    z = ZenohConfig(listen=(f"tcp/127.0.0.1:{port}",), ros2="rmw_zenoh")
    with Bus(z, node_name="litevloc_planner") as bus:
        svc = PlannerService(bus, planner({7: 2}), goal_pose="subgoal").start()
        view = RosNodeView(port)
        try:
            k_goal = view.subscribe(0, "/goal_pose", ros_msgs.POSE_STAMPED)
            dds_img = "sensor_msgs::msg::dds_::Image_/" + REFERENCE_HASHES[ros_msgs.IMAGE]
            dds_odom = "nav_msgs::msg::dds_::Odometry_/" + REFERENCE_HASHES[ros_msgs.ODOMETRY]
            img_pub = view.session.declare_publisher(f"0/litevloc/goal_image_raw/{dds_img}")
            pose_pub = view.session.declare_publisher(f"0/litevloc/pose/{dds_odom}")
            assert svc.pubs["goal_pose"].wait_for_subscribers(5.0)
            deadline = time.monotonic() + 5
            while not (img_pub.matching_status.matching and pose_pub.matching_status.matching):
                assert time.monotonic() < deadline
                time.sleep(0.01)
            pose_pub.put(ros_msgs.serialize(ros_msgs.odometry_msg(5, pose(0.0), "map", "base_link"),
                                            ros_msgs.ODOMETRY))
            a = np.zeros((32, 32, 3), np.uint8)
            a[0, 0, 0] = 7
            msg = ros_msgs.typestore().types[ros_msgs.IMAGE](
                header=ros_msgs.header(0, "kitchen"), height=32, width=32, encoding="rgb8", is_bigendian=0,
                step=96, data=a.reshape(-1))
            img_pub.put(ros_msgs.serialize(msg, ros_msgs.IMAGE))
            first = view.wait(k_goal, 1)
            for k, x in enumerate((0.1, 0.2, 0.95, 1.0)):
                pose_pub.put(ros_msgs.serialize(ros_msgs.odometry_msg(10 + k, pose(x), "map", "base_link"),
                                                ros_msgs.ODOMETRY))
            view.wait(k_goal, 3)
            time.sleep(0.3)  # and no more: the same subgoal is not sent again
            got = view.wait(k_goal, 3)
            xs = [_xy(ros_msgs.deserialize(p, ros_msgs.POSE_STAMPED))[0] for p, _ in got]
            assert xs == pytest.approx([0.0, 1.0, 2.0], abs=1e-3), xs  # the path's nodes 0, 1, 2, each once
            assert [parse_attachment(a)[0] for _, a in got] == [1, 2, 3] and first
            assert svc.planner.status.goal == "kitchen"
        finally:
            view.close()
            svc.close()
