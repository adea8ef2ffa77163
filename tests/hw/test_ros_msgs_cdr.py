"""`ros_msgs.odometry_cdr` (the fused pose's publish path) packs the bytes rosbags serialises."""

from __future__ import annotations

import numpy as np
import pytest

from litevloc.base.geometry import make_T, so3_exp
from litevloc.hw import ros_msgs


def test_odometry_cdr_is_byte_identical_to_the_rosbags_message() -> None:
    rng = np.random.default_rng(7)
    for i in range(300):  # every quaternion branch (small and large rotations), frame names of every length mod 4
        T = make_T(so3_exp(rng.normal(size=3) * (3.0 if i % 2 else 0.01)), rng.normal(size=3) * 10)
        cov = rng.normal(size=(6, 6)) if i % 3 else None
        frame, child = "map" + "x" * (i % 5), "base_link" + "y" * (i % 7)
        t_ns = int(rng.integers(0, 2**31 * 10**9))
        want = ros_msgs.serialize(ros_msgs.odometry_msg(t_ns, T, frame, child, cov), ros_msgs.ODOMETRY)
        assert ros_msgs.odometry_cdr(t_ns, T, frame, child, cov) == want, i


def test_odometry_cdr_decodes_to_the_pose_given() -> None:
    T = make_T(so3_exp(np.array([0.0, 0.0, 3.1])), np.array([1.0, -2.0, 0.5]))  # w near 0: the sign rule
    msg = ros_msgs.deserialize(ros_msgs.odometry_cdr(1_500_000_000_123, T, "map", "base_link", np.eye(6)),
                               ros_msgs.ODOMETRY)
    assert ros_msgs.stamp_ns(msg.header) == 1_500_000_000_123
    assert (msg.header.frame_id, msg.child_frame_id) == ("map", "base_link")
    np.testing.assert_allclose(ros_msgs.pose_to_matrix(msg.pose.pose), T, atol=1e-12)
    assert msg.pose.pose.orientation.w >= 0
    np.testing.assert_array_equal(msg.pose.covariance, np.eye(6).ravel())


def test_odometry_cdr_rejects_a_negative_stamp() -> None:
    with pytest.raises(ValueError, match="negative timestamp"):
        ros_msgs.odometry_cdr(-1, np.eye(4), "map", "base_link")
