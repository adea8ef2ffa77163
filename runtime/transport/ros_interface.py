"""The ROS 2 robot interface's messages (pure: build and check, no I/O).

* `/tf`, `/tf_static`: tf2_msgs/TFMessage of geometry_msgs/TransformStamped (REP-105: the
  localizer publishes `map -> odom`, stamped with the odometry stamp it was computed from).
* `/initialpose`: geometry_msgs/PoseWithCovarianceStamped (RViz's "2D Pose Estimate") ->
  a `SearchRegion` that bounds the next global localization, or a refusal with its reason.
* Goal images as sensor_msgs/Image (rgb8, bgr8, mono8, rgba8, bgra8) -> HxWx3 RGB.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from litevloc.base.errors import LiteVLocError
from litevloc.config.schema import InitialPoseConfig
from litevloc.hw import ros_msgs
from litevloc.pipelines.localization.search_region import SearchRegion

TF_MESSAGE = "tf2_msgs/msg/TFMessage"


def tf_message(transforms: Sequence[tuple[int, NDArray[np.floating], str, str]]) -> object:
    """tf2_msgs/TFMessage from (t_ns, T_parent_child 4x4, parent frame, child frame) tuples."""
    ts = [ros_msgs.transform_stamped_msg(t, T, parent, child) for t, T, parent, child in transforms]
    return ros_msgs.typestore().types[TF_MESSAGE](transforms=ts)


class InitialPoseRefused(LiteVLocError, ValueError):
    """An /initialpose message that must not be applied; the message says why."""


@dataclass(frozen=True, eq=False)
class InitialPose:
    """An accepted initial pose: `T_map_base` (4x4), the radius (metres) of the search around it and
    how long (seconds of sensor time) it bounds the search unless a fix from such a search comes first."""

    t_ns: int
    T_map_base: NDArray[np.float64]
    radius_m: float
    hold_s: float

    def region(self, T_base_camera: NDArray[np.floating]) -> SearchRegion:
        """The search region around the camera position at this pose (map keyframes are camera poses)."""
        T_map_camera = self.T_map_base @ np.asarray(T_base_camera, np.float64)
        return SearchRegion(T_map_camera[:2, 3].copy(), self.radius_m)


def parse_initial_pose(msg: object, map_frame: str, params: InitialPoseConfig) -> InitialPose:
    """Check a decoded PoseWithCovarianceStamped; `InitialPoseRefused` names what is wrong
    (wrong frame id, NaN/inf pose or covariance, non-unit quaternion, a covariance too wide to
    bound anything or not positive semi-definite in x/y).

    Search radius (metres, in the map's x/y plane): `max(min_radius_m, sigmas * sigma)`, sigma the
    standard deviation along the covariance's major x/y axis (ROS order x, y, z, rot x, y, z)."""
    frame = str(msg.header.frame_id)  # type: ignore[attr-defined]
    if frame.lstrip("/") != map_frame:
        raise InitialPoseRefused(f"initial pose frame_id {frame!r} is not the map frame {map_frame!r}")
    try:
        T = ros_msgs.pose_to_matrix(msg.pose.pose)  # type: ignore[attr-defined]
    except ros_msgs.MessageDecodeError as exc:
        raise InitialPoseRefused(f"initial pose: {exc}") from exc
    cov = np.asarray(msg.pose.covariance, dtype=np.float64).reshape(6, 6)  # type: ignore[attr-defined]
    if not np.all(np.isfinite(cov)):
        raise InitialPoseRefused("initial pose covariance contains NaN or infinity")
    cxy = cov[:2, :2]
    if abs(cxy[0, 1] - cxy[1, 0]) > 1e-9 * max(1.0, float(np.abs(cxy).max())):
        raise InitialPoseRefused("initial pose x/y covariance is not symmetric")
    eig = np.linalg.eigvalsh(cxy)
    if eig[0] < -1e-12:
        raise InitialPoseRefused(f"initial pose x/y covariance is not positive semi-definite (eigenvalues {eig})")
    sigma = float(np.sqrt(max(eig[1], 0.0)))
    if sigma > params.max_sigma_m:
        raise InitialPoseRefused(f"initial pose standard deviation {sigma:.1f} m > zenoh.initial_pose.max_sigma_m "
                                 f"({params.max_sigma_m:g} m): it bounds nothing")
    radius = max(params.min_radius_m, params.sigmas * sigma)
    return InitialPose(ros_msgs.stamp_ns(msg.header), T, radius, params.hold_s)  # type: ignore[attr-defined]


_CHANNELS = {"rgb8": 3, "bgr8": 3, "rgba8": 4, "bgra8": 4, "mono8": 1}


def image_to_rgb(msg: object) -> NDArray[np.uint8]:
    """sensor_msgs/Image (8-bit rgb/bgr/rgba/bgra/mono) -> HxWx3 uint8 RGB; ValueError when the
    encoding is not one of those or the layout is inconsistent."""
    enc = str(msg.encoding).lower()  # type: ignore[attr-defined]
    if enc not in _CHANNELS:
        raise ValueError(f"goal image encoding {enc!r} is not one of {sorted(_CHANNELS)}")
    c = _CHANNELS[enc]
    h, w, step = int(msg.height), int(msg.width), int(msg.step)  # type: ignore[attr-defined]
    data = np.asarray(msg.data, dtype=np.uint8)  # type: ignore[attr-defined]
    if h < 16 or w < 16 or step < w * c or data.size != step * h:
        raise ValueError(f"goal image layout inconsistent: {w}x{h} {enc}, step {step}, {data.size} bytes")
    px = data.reshape(h, step)[:, : w * c].reshape(h, w, c)
    if enc == "mono8":
        return np.ascontiguousarray(np.repeat(px, 3, axis=2))
    rgb = px[:, :, :3] if enc.startswith("rgb") else px[:, :, 2::-1]
    return np.ascontiguousarray(rgb)
