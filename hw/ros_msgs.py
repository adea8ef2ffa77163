"""ROS 2 message construction, CDR encoding and decoding (via the `rosbags` typestore).

One place converts between LiteVLoc's numpy types and ROS 2 messages, so recordings
(MCAP) and the wire (Zenoh) carry the same bytes that `ros2 bag`, Foxglove and
`zenoh-bridge-ros2dds` understand. Type store: ROS 2 Humble definitions.

Stamps: `builtin_interfaces/Time` (sec, nanosec) <-> int nanoseconds.
Quaternions: ROS order x, y, z, w (as in `pipelines.geometry`).
"""

from __future__ import annotations

import math
import struct
from functools import lru_cache
from typing import Any

import numpy as np
from numpy.typing import NDArray
from rosbags.typesys import Stores, get_typestore

from litevloc.base.errors import LiteVLocError
from litevloc.base.geometry import make_T, matrix_to_quat_xyzw, quat_xyzw_to_matrix

COMPRESSED_IMAGE = "sensor_msgs/msg/CompressedImage"
IMAGE = "sensor_msgs/msg/Image"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
ODOMETRY = "nav_msgs/msg/Odometry"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
POSE_COV_STAMPED = "geometry_msgs/msg/PoseWithCovarianceStamped"
TRANSFORM_STAMPED = "geometry_msgs/msg/TransformStamped"
STRING = "std_msgs/msg/String"
DIAGNOSTIC_ARRAY = "diagnostic_msgs/msg/DiagnosticArray"


class MessageDecodeError(LiteVLocError, ValueError):
    """A CDR payload or a decoded message is malformed; the message says what is wrong."""


@lru_cache(maxsize=1)
def typestore() -> Any:
    return get_typestore(Stores.ROS2_HUMBLE)


def msgdef(typename: str) -> str:
    """The ROS 2 `.msg` definition text (with dependencies) for an MCAP schema record."""
    text, _ = typestore().generate_msgdef(typename, ros_version=2)
    return str(text)


def serialize(msg: Any, typename: str) -> bytes:
    return bytes(typestore().serialize_cdr(msg, typename))


def deserialize(data: bytes | memoryview, typename: str) -> Any:
    """CDR bytes -> message object; MessageDecodeError on any malformed payload."""
    try:
        return typestore().deserialize_cdr(data, typename)
    except Exception as exc:  # rosbags raises assorted errors on truncated/garbled CDR
        raise MessageDecodeError(f"cannot decode {typename} CDR payload ({len(data)} bytes): {exc}") from exc


def _t(name: str) -> Any:
    return typestore().types[name]


def stamp(t_ns: int) -> Any:
    if t_ns < 0:
        raise ValueError(f"negative timestamp {t_ns}")
    return _t("builtin_interfaces/msg/Time")(sec=int(t_ns // 1_000_000_000), nanosec=int(t_ns % 1_000_000_000))


def header(t_ns: int, frame_id: str) -> Any:
    return _t("std_msgs/msg/Header")(stamp=stamp(t_ns), frame_id=frame_id)


def stamp_ns(hdr: Any) -> int:
    return int(hdr.stamp.sec) * 1_000_000_000 + int(hdr.stamp.nanosec)


def pose_msg(T: NDArray[np.floating]) -> Any:
    T = np.asarray(T, dtype=np.float64)
    q = matrix_to_quat_xyzw(T[:3, :3])
    return _t("geometry_msgs/msg/Pose")(
        position=_t("geometry_msgs/msg/Point")(x=float(T[0, 3]), y=float(T[1, 3]), z=float(T[2, 3])),
        orientation=_t("geometry_msgs/msg/Quaternion")(x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3])),
    )


def pose_to_matrix(pose: Any) -> NDArray[np.float64]:
    """geometry_msgs/Pose -> 4x4; MessageDecodeError on NaN or a zero quaternion."""
    p, o = pose.position, pose.orientation
    t = np.array([p.x, p.y, p.z], dtype=np.float64)
    q = np.array([o.x, o.y, o.z, o.w], dtype=np.float64)
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(q))):
        raise MessageDecodeError("pose contains NaN or infinity")
    n = float(np.linalg.norm(q))
    if abs(n - 1.0) > 1e-3:
        raise MessageDecodeError(f"pose quaternion is not unit length (norm {n:.6f})")
    return make_T(quat_xyzw_to_matrix(q), t)


def _cov36(cov: NDArray[np.floating] | None) -> NDArray[np.float64]:
    if cov is None:
        return np.zeros(36)
    c = np.asarray(cov, dtype=np.float64)
    if c.shape != (6, 6):
        raise ValueError(f"covariance must be 6x6, got {c.shape}")
    return c.reshape(36).copy()


def odometry_msg(
    t_ns: int,
    T_parent_child: NDArray[np.floating],
    frame_id: str,
    child_frame_id: str,
    covariance: NDArray[np.floating] | None = None,
    twist: NDArray[np.floating] | None = None,
) -> Any:
    """nav_msgs/Odometry with pose (and optional 6-vector twist: vx vy vz wx wy wz)."""
    tw = np.zeros(6) if twist is None else np.asarray(twist, dtype=np.float64).reshape(6)
    return _t(ODOMETRY)(
        header=header(t_ns, frame_id),
        child_frame_id=child_frame_id,
        pose=_t("geometry_msgs/msg/PoseWithCovariance")(pose=pose_msg(T_parent_child), covariance=_cov36(covariance)),
        twist=_t("geometry_msgs/msg/TwistWithCovariance")(
            twist=_t("geometry_msgs/msg/Twist")(
                linear=_t("geometry_msgs/msg/Vector3")(x=tw[0], y=tw[1], z=tw[2]),
                angular=_t("geometry_msgs/msg/Vector3")(x=tw[3], y=tw[4], z=tw[5]),
            ),
            covariance=np.zeros(36),
        ),
    )


def pose_stamped_msg(t_ns: int, T: NDArray[np.floating], frame_id: str) -> Any:
    return _t(POSE_STAMPED)(header=header(t_ns, frame_id), pose=pose_msg(T))


def pose_cov_stamped_msg(
    t_ns: int, T: NDArray[np.floating], frame_id: str, covariance: NDArray[np.floating] | None
) -> Any:
    return _t(POSE_COV_STAMPED)(
        header=header(t_ns, frame_id),
        pose=_t("geometry_msgs/msg/PoseWithCovariance")(pose=pose_msg(T), covariance=_cov36(covariance)),
    )


def transform_stamped_msg(t_ns: int, T: NDArray[np.floating], frame_id: str, child_frame_id: str) -> Any:
    T = np.asarray(T, dtype=np.float64)
    q = matrix_to_quat_xyzw(T[:3, :3])
    return _t(TRANSFORM_STAMPED)(
        header=header(t_ns, frame_id),
        child_frame_id=child_frame_id,
        transform=_t("geometry_msgs/msg/Transform")(
            translation=_t("geometry_msgs/msg/Vector3")(x=T[0, 3], y=T[1, 3], z=T[2, 3]),
            rotation=_t("geometry_msgs/msg/Quaternion")(x=q[0], y=q[1], z=q[2], w=q[3]),
        ),
    )


def compressed_image_msg(t_ns: int, data: bytes, fmt: str, frame_id: str) -> Any:
    return _t(COMPRESSED_IMAGE)(header=header(t_ns, frame_id), format=fmt, data=np.frombuffer(data, dtype=np.uint8))


def depth_image_msg(t_ns: int, depth_mm: NDArray[np.uint16], frame_id: str) -> Any:
    """sensor_msgs/Image, encoding 16UC1 (millimetres, 0 = invalid), little endian."""
    d = np.ascontiguousarray(depth_mm, dtype="<u2")
    h, w = d.shape
    return _t(IMAGE)(
        header=header(t_ns, frame_id), height=h, width=w, encoding="16UC1", is_bigendian=0, step=w * 2,
        data=d.view(np.uint8).reshape(-1),
    )


def depth_image_to_mm(msg: Any) -> NDArray[np.uint16]:
    """sensor_msgs/Image 16UC1 -> HxW uint16; MessageDecodeError on a mismatched layout."""
    if msg.encoding.upper() not in ("16UC1", "MONO16"):
        raise MessageDecodeError(f"depth image encoding must be 16UC1, got {msg.encoding!r}")
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    if h <= 0 or w <= 0 or step < 2 * w or len(msg.data) != step * h:
        raise MessageDecodeError(
            f"depth image layout inconsistent: {w}x{h}, step {step}, {len(msg.data)} bytes"
        )
    dt = ">u2" if msg.is_bigendian else "<u2"
    rows = np.asarray(msg.data, dtype=np.uint8).reshape(h, step)[:, : 2 * w]
    return np.ascontiguousarray(rows).view(dt).reshape(h, w).astype(np.uint16)


def camera_info_msg(t_ns: int, K: NDArray[np.floating], width: int, height: int, frame_id: str) -> Any:
    K = np.asarray(K, dtype=np.float64)
    P = np.zeros((3, 4))
    P[:, :3] = K
    return _t(CAMERA_INFO)(
        header=header(t_ns, frame_id), height=height, width=width, distortion_model="plumb_bob",
        d=np.zeros(5), k=K.reshape(9).copy(), r=np.eye(3).reshape(9), p=P.reshape(12),
        binning_x=0, binning_y=0,
        roi=_t("sensor_msgs/msg/RegionOfInterest")(x_offset=0, y_offset=0, height=0, width=0, do_rectify=False),
    )


def camera_info_K(msg: Any) -> NDArray[np.float64]:
    K = np.asarray(msg.k, dtype=np.float64).reshape(3, 3)
    if not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise MessageDecodeError(f"camera_info K is invalid: {K.tolist()}")
    return K


def odometry_to_matrix(msg: Any) -> tuple[int, NDArray[np.float64], NDArray[np.float64] | None]:
    """nav_msgs/Odometry -> (t_ns, T_frame_child 4x4, 6x6 pose covariance or None).

    An all-zero covariance means "unknown" in ROS and is returned as None."""
    T = pose_to_matrix(msg.pose.pose)
    cov = np.asarray(msg.pose.covariance, dtype=np.float64).reshape(6, 6)
    return stamp_ns(msg.header), T, (None if not np.any(cov) else cov)


def diagnostic_array_msg(
    t_ns: int, statuses: list[tuple[int, str, str, str, list[tuple[str, str]]]], frame_id: str = ""
) -> Any:
    """diagnostic_msgs/DiagnosticArray from (level, name, message, hardware_id, [(key, value)])
    tuples; level 0 OK, 1 WARN, 2 ERROR, 3 STALE (the message's `byte` constants)."""
    st, kv = _t("diagnostic_msgs/msg/DiagnosticStatus"), _t("diagnostic_msgs/msg/KeyValue")
    out = []
    for level, name, message, hw_id, values in statuses:
        if level not in (0, 1, 2, 3):
            raise ValueError(f"diagnostic level must be 0..3, got {level}")
        out.append(st(level=int(level), name=name, message=message, hardware_id=hw_id,
                      values=[kv(key=str(k), value=str(v)) for k, v in values]))
    return _t(DIAGNOSTIC_ARRAY)(header=header(t_ns, frame_id), status=out)


_CDR_LE = b"\x00\x01\x00\x00"  # CDR encapsulation: plain CDR, little-endian


def _cdr_string(buf: bytearray, text: str) -> None:
    """Append a CDR string (uint32 length with the NUL, bytes, NUL), aligned to 4 first;
    offsets count from after the encapsulation header, as CDR aligns."""
    _cdr_align(buf, 4)
    data = text.encode()
    buf += struct.pack("<I", len(data) + 1) + data + b"\x00"


def _cdr_align(buf: bytearray, n: int) -> None:
    buf += b"\x00" * (-(len(buf) - len(_CDR_LE)) % n)


def _quat_xyzw(R: list[list[float]]) -> tuple[float, float, float, float]:
    """`matrix_to_quat_xyzw` on Python floats (Shepperd's method, w >= 0): the same branches
    without numpy's per-scalar overhead."""
    (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = R
    tr = r00 + r11 + r22
    if tr > 0:
        s = 2.0 * math.sqrt(tr + 1.0)
        w, x, y, z = 0.25 * s, (r21 - r12) / s, (r02 - r20) / s, (r10 - r01) / s
    elif r00 > r11 and r00 > r22:
        s = 2.0 * math.sqrt(1.0 + r00 - r11 - r22)
        w, x, y, z = (r21 - r12) / s, 0.25 * s, (r01 + r10) / s, (r02 + r20) / s
    elif r11 > r22:
        s = 2.0 * math.sqrt(1.0 + r11 - r00 - r22)
        w, x, y, z = (r02 - r20) / s, (r01 + r10) / s, 0.25 * s, (r12 + r21) / s
    else:
        s = 2.0 * math.sqrt(1.0 + r22 - r00 - r11)
        w, x, y, z = (r10 - r01) / s, (r02 + r20) / s, (r12 + r21) / s, 0.25 * s
    n = math.sqrt(x * x + y * y + z * z + w * w) * (-1.0 if w < 0 else 1.0)
    return x / n, y / n, z / n, w / n


def odometry_cdr(t_ns: int, T_parent_child: NDArray[np.floating], frame_id: str, child_frame_id: str,
                 covariance: NDArray[np.floating] | None = None) -> bytes:
    """The CDR bytes of `serialize(odometry_msg(...), ODOMETRY)` (zero twist), packed directly:
    the fused pose's publish path, where building the message objects cost ~5x the packing."""
    if t_ns < 0:
        raise ValueError(f"negative timestamp {t_ns}")
    T = np.asarray(T_parent_child, dtype=np.float64)
    q = _quat_xyzw(T[:3, :3].tolist())
    buf = bytearray(_CDR_LE)
    buf += struct.pack("<iI", t_ns // 1_000_000_000, t_ns % 1_000_000_000)
    _cdr_string(buf, frame_id)
    _cdr_string(buf, child_frame_id)
    _cdr_align(buf, 8)
    buf += struct.pack("<7d", T[0, 3], T[1, 3], T[2, 3], q[0], q[1], q[2], q[3])
    buf += _cov36(covariance).tobytes()
    buf += bytes(8 * (6 + 36))  # twist (zero) and its covariance (zero)
    return bytes(buf)
