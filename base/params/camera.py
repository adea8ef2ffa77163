"""OAK-D camera settings (config section `camera`); the driver is `litevloc.hw.oak`."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

StereoPreset = Literal["default", "density", "accuracy", "fast_density", "fast_accuracy", "robotics", "high_detail"]


@dataclass(frozen=True)
class CameraConfig:
    """OAK-D camera settings (config section `camera`).

    Colour is CAM_A, the stereo pair CAM_B/CAM_C (OAK-D, OAK-D Lite, OAK-D Pro, S2).
    """

    # device id (MxID), name or IP of the OAK; "" = the first device found
    device_id: str = ""
    # colour (and aligned depth) output width (pixels)
    width: int = 640
    # colour (and aligned depth) output height (pixels)
    height: int = 480
    # frame rate (Hz)
    fps: float = 15.0
    # "aligned": on-device stereo depth registered to colour; "off": no depth
    depth: Literal["aligned", "off"] = "aligned"
    # mono pair width fed to the stereo engine (pixels; OV9282: 1280x800 or 640x400)
    stereo_width: int = 640
    # mono pair height fed to the stereo engine (pixels)
    stereo_height: int = 400
    # depthai's stereo preset
    stereo_preset: StereoPreset = "default"
    # on-device left-right consistency check of the stereo depth
    left_right_check: bool = True
    # sub-pixel disparity (finer depth far away)
    subpixel: bool = True
    # extended disparity: closer minimum depth, at a cost in rate
    extended_disparity: bool = False
    # undistort colour on the device, so K is a pinhole model
    undistort: bool = True
    # which instant of the exposure a frame is stamped with
    timestamp_at: Literal["start", "middle", "end"] = "middle"
    # stamp clock: host wall clock (lines up with ROS odometry) or monotonic
    clock: Literal["realtime", "monotonic"] = "realtime"
    # > 0: JPEG round trip on the host when recording, so a recording holds the live pixels; 0 = raw
    jpeg_quality: int = 95
    # also stream the IMU
    imu: bool = False
    # IMU rate (Hz)
    imu_rate_hz: int = 200
    # depthai output queue size (messages)
    queue_size: int = 4
    # how long to look for the device before failing (s)
    discovery_timeout_s: float = 2.0
    # device boot + first frame, longest wait (s)
    first_frame_timeout_s: float = 15.0
    # then the longest gap between frames before failing (s)
    frame_timeout_s: float = 2.0
    # frame_id of the colour frames
    frame_id: str = "camera"

    def __post_init__(self) -> None:
        for name in ("width", "height", "stereo_width", "stereo_height"):
            v = getattr(self, name)
            if not (16 <= v <= 8192):
                raise ValueError(f"{name} must be in [16, 8192] pixels, got {v}")
        if self.width % 2 or self.height % 2:
            raise ValueError(f"colour size must be even, got {self.width}x{self.height}")
        if not (0 < self.fps <= 120):
            raise ValueError(f"fps must be in (0, 120], got {self.fps}")
        if not (0 <= self.jpeg_quality <= 100):
            raise ValueError(f"jpeg_quality must be in [0, 100], got {self.jpeg_quality}")
        if self.imu and not (1 <= self.imu_rate_hz <= 1000):
            raise ValueError(f"imu_rate_hz must be in [1, 1000], got {self.imu_rate_hz}")
        if not (1 <= self.queue_size <= 64):
            raise ValueError(f"queue_size must be in [1, 64], got {self.queue_size}")
        for name in ("discovery_timeout_s", "first_frame_timeout_s", "frame_timeout_s"):
            v = getattr(self, name)
            if not (0 < v <= 600):
                raise ValueError(f"{name} must be in (0, 600] seconds, got {v}")
        if not self.frame_id:
            raise ValueError("frame_id must not be empty")
