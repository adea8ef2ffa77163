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

    device_id: str = ""  # device id (MxID), name or IP; "" = the first device found
    width: int = 640  # colour (and aligned depth) output size, pixels
    height: int = 480
    fps: float = 15.0
    depth: Literal["aligned", "off"] = "aligned"  # stereo depth registered to colour, or no depth
    stereo_width: int = 640  # mono pair resolution fed to the stereo engine
    stereo_height: int = 400
    stereo_preset: StereoPreset = "default"
    left_right_check: bool = True
    subpixel: bool = True
    extended_disparity: bool = False  # closer minimum depth, at a cost in rate
    undistort: bool = True  # undistort colour on device, so K is a pinhole model
    timestamp_at: Literal["start", "middle", "end"] = "middle"  # which instant of the exposure
    clock: Literal["realtime", "monotonic"] = "realtime"
    # 0 = pass raw colour; >0 = JPEG round trip on host when recording (`litevloc record`: the
    # recording then holds the live pixels); `litevloc run` records nothing and skips it
    jpeg_quality: int = 95
    imu: bool = False
    imu_rate_hz: int = 200
    queue_size: int = 4
    discovery_timeout_s: float = 2.0  # how long to look for the device before failing
    first_frame_timeout_s: float = 15.0  # device boot + first frame
    frame_timeout_s: float = 2.0  # then: longest gap between frames before failing
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
