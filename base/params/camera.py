"""OAK-D camera settings (config section `camera`); the driver is `litevloc.hw.oak`."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

from litevloc.base.settings import Settings, setting

StereoPreset = Literal["default", "density", "accuracy", "fast_density", "fast_accuracy", "robotics", "high_detail"]


@dataclass(frozen=True)
class CameraConfig(Settings):
    """OAK-D camera settings (config section `camera`).

    Colour is CAM_A, the stereo pair CAM_B/CAM_C (OAK-D, OAK-D Lite, OAK-D Pro, S2).
    """

    device_id: str = setting("", "device id (MxID), name or IP of the OAK; \"\" = the first device found")
    width: int = setting(640, "colour (and aligned depth) output width; even", unit="px", low=16, high=8192)
    height: int = setting(480, "colour (and aligned depth) output height; even", unit="px", low=16, high=8192)
    fps: float = setting(15.0, "camera frame rate", unit="Hz", low=0, low_open=True, high=120)
    depth: Literal["aligned", "off"] = setting(
        "aligned", "\"aligned\": on-device stereo depth registered to colour; \"off\": no depth")
    stereo_width: int = setting(
        640, "mono pair width fed to the stereo engine (OV9282: 1280x800 or 640x400)", unit="px", low=16, high=8192)
    stereo_height: int = setting(400, "mono pair height fed to the stereo engine", unit="px", low=16, high=8192)
    stereo_preset: StereoPreset = setting("default", "depthai's stereo preset")
    left_right_check: bool = setting(True, "on-device left-right consistency check of the stereo depth")
    subpixel: bool = setting(True, "sub-pixel disparity (finer depth far away)")
    extended_disparity: bool = setting(False, "extended disparity: closer minimum depth, at a cost in rate")
    undistort: bool = setting(True, "undistort colour on the device, so K is a pinhole model")
    timestamp_at: Literal["start", "middle", "end"] = setting(
        "middle", "which instant of the exposure a frame is stamped with")
    clock: Literal["realtime", "monotonic"] = setting(
        "realtime", "stamp clock: host wall clock (lines up with ROS odometry) or monotonic")
    jpeg_quality: int = setting(
        95, "JPEG quality of a host round trip when recording, so a recording holds the live pixels (0 = raw)",
        low=0, high=100)
    imu: bool = setting(False, "also stream the IMU")
    imu_rate_hz: int = setting(200, "IMU sample rate, in [1, 1000] when `imu` is on", unit="Hz", low=-math.inf)
    queue_size: int = setting(4, "depthai output queue size (messages)", low=1, high=64)
    discovery_timeout_s: float = setting(
        2.0, "how long to look for the device before failing", unit="s", low=0, low_open=True, high=600)
    first_frame_timeout_s: float = setting(
        15.0, "longest wait for the device to boot and send its first frame", unit="s", low=0, low_open=True, high=600)
    frame_timeout_s: float = setting(
        2.0, "longest gap between frames after the first before failing", unit="s", low=0, low_open=True, high=600)
    frame_id: str = setting("camera", "frame_id of the colour frames")

    def check_relations(self) -> None:
        if self.width % 2 or self.height % 2:
            raise ValueError(f"colour size must be even, got {self.width}x{self.height}")
        if self.imu and not (1 <= self.imu_rate_hz <= 1000):
            raise ValueError(f"imu_rate_hz must be in [1, 1000] while imu is on, got {self.imu_rate_hz}")
        if not self.frame_id:
            raise ValueError("frame_id must not be empty")
