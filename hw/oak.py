"""Luxonis OAK-D driver (depthai v3): colour + stereo depth aligned to colour, optional IMU.

`OakSource` is a `StreamSource` yielding the same `RgbdFrame`s as the recorded-stream
readers, so everything downstream (recorder, localization runtime) is source-agnostic.

Design: the device-dependent part is thin (`_build_pipeline`, `OakSource.__iter__`);
everything that can run without a device is a plain function tested host-side with
depthai objects built on the host (`dai.ImgFrame`, `dai.MessageGroup`,
`dai.CalibrationHandler`, `dai.ImgTransformation`):

* `find_device`: discovery with `dai.Device.getAllAvailableDevices()` (about 0.5 s per
  poll), polled for `CameraConfig.discovery_timeout_s`; raises `OakNotFoundError`
  ("no OAK device found ...") instead of the ~11 s search of `dai.Pipeline()`/`dai.Device()`.
* `intrinsics_from_calibration` / `intrinsics_from_frame`: K of the colour image at the
  requested size. The frame's own `ImgTransformation` (v3; it accounts for the sensor
  mode's crop/binning, the ISP resize and undistortion) is preferred; the EEPROM
  calibration scaled to the output size is the fallback.
* `HostClock`: timestamps. depthai syncs the device clock to the host and
  `ImgFrame.getTimestamp()` returns a `timedelta` on the host's `std::chrono::steady_clock`
  (= `CLOCK_MONOTONIC` on Linux = Python's `time.monotonic_ns()`; see
  tests/hw/test_oak.py which checks `dai.Clock.now()` against it). `HostClock` maps that to
  int ns, either kept monotonic (`clock: monotonic`) or shifted to the wall clock
  (`clock: realtime`, default) by an offset `time.time_ns() - time.monotonic_ns()`
  measured ONCE when the stream starts (so stamps never jump when NTP slews the wall
  clock mid-run). Realtime matches ROS header stamps of odometry from the robot, which
  fusion aligns against. Resolution is 1 µs (the `timedelta` resolution).
* `rgbd_from_dai`: `ImgFrame` colour (+ RAW16 depth in mm) -> `RgbdFrame` (RGB uint8,
  float32 metres with 0 -> NaN via `depth_from_millimetres`).

depthai is imported lazily, so importing this module (e.g. from the config schema) costs
nothing and works where depthai is absent.
"""

from __future__ import annotations

import datetime
import logging
import time
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any, Literal

import cv2
import numpy as np
from numpy.typing import NDArray

from litevloc.base.params.camera import CameraConfig
from litevloc.hw.messages import (
    Message,
    RgbdFrame,
    StreamError,
    StreamStats,
    decode_color,
    depth_from_millimetres,
)

log = logging.getLogger(__name__)


class OakNotFoundError(StreamError):
    """No OAK device is connected (or not the configured one)."""


@dataclass(frozen=True)
class ImuSample:
    """One IMU sample in the IMU frame: accelerometer m/s^2, gyroscope rad/s (float64 (3,))."""

    t_ns: int
    accel: NDArray[np.float64]
    gyro: NDArray[np.float64]


def import_depthai() -> Any:
    """Import depthai, or raise StreamError saying how to install it."""
    try:
        import depthai
    except ImportError as exc:  # pragma: no cover - depthai is a dependency
        raise StreamError(f"the OAK-D driver needs the depthai package (pip install 'depthai>=3'): {exc}") from exc
    return depthai


# ----------------------------------------------------------------------------- discovery


def find_device(cfg: CameraConfig, list_devices: Any = None, list_connected: Any = None) -> Any:
    """Return the `dai.DeviceInfo` of the configured device, polling up to `discovery_timeout_s`.

    `list_devices`/`list_connected` (for tests) replace `dai.Device.getAllAvailableDevices`
    and `getAllConnectedDevices` (the latter, asked once on failure, tells a device that is
    present but held by another process). Raises `OakNotFoundError` naming the devices
    seen; never blocks on the ~11 s default device search.
    """
    if list_devices is None:
        list_devices = import_depthai().Device.getAllAvailableDevices
    if list_connected is None:
        list_connected = import_depthai().Device.getAllConnectedDevices
    deadline = time.monotonic() + cfg.discovery_timeout_s
    seen: list[str] = []
    while True:
        infos = list(list_devices())
        seen = [f"{_info_id(i)} ({_info_name(i)})" for i in infos]
        for info in infos:
            if not cfg.device_id or cfg.device_id in (_info_id(info), _info_name(info)):
                return info
        if time.monotonic() + 0.2 >= deadline:
            break
        time.sleep(0.2)
    busy = [i for i in list_connected()
            if (not cfg.device_id or cfg.device_id in (_info_id(i), _info_name(i)))
            and _info_id(i) not in {_info_id(j) for j in infos}]
    if busy:
        raise OakNotFoundError(
            f"OAK device {_info_id(busy[0])} is connected but not available (in use by another process?); "
            "close the other program (or unplug and replug the camera)"
        )
    if cfg.device_id:
        raise OakNotFoundError(
            f"no OAK device found with id or name {cfg.device_id!r} within {cfg.discovery_timeout_s:g} s "
            f"(available: {', '.join(seen) if seen else 'none'}); check camera.device_id"
        )
    raise OakNotFoundError(
        f"no OAK device found within {cfg.discovery_timeout_s:g} s: is the camera plugged in (USB3), powered, "
        "and is the udev rule for Movidius devices (03e7) installed? In a container, pass /dev/bus/usb through."
    )


def _info_id(info: Any) -> str:
    getter = getattr(info, "getDeviceId", None)
    return str(getter() if callable(getter) else getattr(info, "deviceId", ""))


def _info_name(info: Any) -> str:
    return str(getattr(info, "name", ""))


# ----------------------------------------------------------------------------- time


def timedelta_to_ns(td: datetime.timedelta) -> int:
    """Exact integer nanoseconds of a `timedelta` (µs resolution; no float rounding)."""
    return ((td.days * 86400 + td.seconds) * 1_000_000 + td.microseconds) * 1000


@dataclass(frozen=True)
class HostClock:
    """Maps depthai host-synced steady-clock stamps to LiteVLoc `t_ns`.

    `t_ns = steady_ns + offset_ns`; `offset_ns` is 0 for `monotonic`, and the wall-clock
    minus monotonic-clock offset, measured once, for `realtime`.
    """

    kind: Literal["realtime", "monotonic"]
    offset_ns: int

    @classmethod
    def measure(cls, kind: Literal["realtime", "monotonic"], samples: int = 5) -> HostClock:
        """Measure the realtime-monotonic offset (the tightest of a few bracketed samples)."""
        if kind == "monotonic":
            return cls(kind, 0)
        best: tuple[int, int] | None = None
        for _ in range(max(1, samples)):
            m0 = time.monotonic_ns()
            wall = time.time_ns()
            m1 = time.monotonic_ns()
            if best is None or m1 - m0 < best[0]:
                best = (m1 - m0, wall - (m0 + m1) // 2)
        assert best is not None
        return cls(kind, best[1])

    def to_host_ns(self, steady: datetime.timedelta | int) -> int:
        """A depthai `getTimestamp()` value (timedelta, or int steady-clock ns) -> t_ns."""
        ns = timedelta_to_ns(steady) if isinstance(steady, datetime.timedelta) else int(steady)
        return ns + self.offset_ns


# ----------------------------------------------------------------------------- calibration


def _socket(name: str) -> Any:
    dai = import_depthai()
    return getattr(dai.CameraBoardSocket, name)


def intrinsics_from_calibration(calib: Any, width: int, height: int, socket: str = "CAM_A") -> NDArray[np.float64]:
    """3x3 float64 K of camera `socket` at output size `width`x`height` from a `dai.CalibrationHandler`.

    depthai scales the EEPROM intrinsics (stored at the calibration resolution) to the
    requested size, keeping the aspect ratio and cropping the other side centrally.
    Raises StreamError if the calibration has no such camera or K is not a pinhole matrix.
    """
    try:
        K = np.asarray(calib.getCameraIntrinsics(_socket(socket), int(width), int(height)), dtype=np.float64)
    except RuntimeError as exc:
        raise StreamError(f"OAK calibration has no intrinsics for {socket}: {exc}") from exc
    return _check_K(K, f"calibration of {socket} at {width}x{height}")


def intrinsics_from_frame(frame: Any) -> NDArray[np.float64] | None:
    """K of an `ImgFrame` from its v3 `ImgTransformation`, or None if the frame carries none.

    The transformation tracks sensor-mode crop/binning, ISP scaling and crops, so it is the
    exact K of the delivered pixels.
    """
    tr = frame.getTransformation()
    if tr is None or not tr.isValid():
        return None
    w, h = tr.getSize()
    if (int(w), int(h)) != (frame.getWidth(), frame.getHeight()):
        return None
    return _check_K(np.asarray(tr.getIntrinsicMatrix(), dtype=np.float64), "frame transformation")


def _check_K(K: NDArray[np.float64], where: str) -> NDArray[np.float64]:
    if K.shape != (3, 3) or not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise StreamError(f"invalid intrinsics from {where}: {K.tolist()}")
    if abs(K[0, 1]) > 1e-9 or np.any(np.abs(K[2] - (0.0, 0.0, 1.0)) > 1e-9) or abs(K[1, 0]) > 1e-9:
        raise StreamError(f"intrinsics from {where} are not a pinhole matrix: {K.tolist()}")
    return K


# ----------------------------------------------------------------------------- messages


def color_from_imgframe(frame: Any) -> NDArray[np.uint8]:
    """Colour `ImgFrame` (RGB888i/BGR888i/NV12/...) -> HxWx3 uint8 RGB, C-contiguous."""
    dai = import_depthai()
    kind = frame.getType()
    if kind == dai.ImgFrame.Type.RGB888i:
        img = np.asarray(frame.getFrame())
    elif kind == dai.ImgFrame.Type.BGR888i:
        img = np.asarray(frame.getFrame())[:, :, ::-1]
    else:
        img = np.asarray(frame.getCvFrame())  # OpenCV conversion to BGR
        if img.ndim == 2:
            img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
        img = img[:, :, ::-1]
    if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8:
        raise StreamError(f"unsupported colour frame {kind}: array {img.shape} {img.dtype}")
    return np.ascontiguousarray(img)


def depth_mm_from_imgframe(frame: Any) -> NDArray[np.uint16]:
    """RAW16 depth `ImgFrame` (uint16 millimetres, 0 = invalid) -> HxW uint16."""
    mm = np.asarray(frame.getFrame())
    if mm.ndim != 2 or mm.dtype != np.uint16:
        raise StreamError(f"depth frame must be HxW uint16 millimetres, got {mm.shape} {mm.dtype}")
    return mm


def exposure_offset(at: Literal["start", "middle", "end"]) -> Any:
    return getattr(import_depthai().CameraExposureOffset, at.upper())


def rgbd_from_dai(
    color: Any,
    depth: Any | None,
    clock: HostClock,
    K_fallback: NDArray[np.float64] | None,
    index: int,
    frame_id: str = "camera",
    timestamp_at: Literal["start", "middle", "end"] = "middle",
    jpeg_quality: int = 0,
) -> RgbdFrame:
    """depthai colour (+ aligned depth) frames -> `RgbdFrame`.

    K is the colour frame's own transformation intrinsics where present, else
    `K_fallback` (from the calibration). With `jpeg_quality > 0` the colour is JPEG
    encoded here and the *decoded* image is returned with the bytes, so the live run sees
    exactly the pixels a recording of it replays. Raises StreamError on inconsistent input.
    """
    rgb = color_from_imgframe(color)
    h, w = rgb.shape[:2]
    t_ns = clock.to_host_ns(color.getTimestamp(exposure_offset(timestamp_at)))
    K = intrinsics_from_frame(color)
    if K is None:
        if K_fallback is None:
            raise StreamError("colour frame has no intrinsics and no calibration fallback was given")
        K = K_fallback
    depth_m = None
    if depth is not None:
        mm = depth_mm_from_imgframe(depth)
        if mm.shape != (h, w):
            raise StreamError(
                f"depth {mm.shape[1]}x{mm.shape[0]} is not aligned to colour {w}x{h} (frame {index})"
            )
        depth_m = depth_from_millimetres(mm)
    jpeg = None
    if jpeg_quality > 0:
        ok, enc = cv2.imencode(".jpg", rgb[:, :, ::-1], [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)])
        if not ok:
            raise StreamError(f"JPEG encoding failed for frame {index}")
        jpeg = enc.tobytes()
        rgb = decode_color(jpeg, f"OAK frame {index}")
    return RgbdFrame(t_ns=t_ns, color=rgb, depth=depth_m, K=np.array(K, dtype=np.float64), index=index,
                     frame_id=frame_id, color_jpeg=jpeg)


def imu_samples_from_dai(imu_data: Any, clock: HostClock) -> list[ImuSample]:
    """`dai.IMUData` -> samples (stamped at the gyroscope report; accel from the same packet)."""
    out = []
    for pkt in imu_data.packets:
        a, g = pkt.acceleroMeter, pkt.gyroscope
        out.append(ImuSample(
            t_ns=clock.to_host_ns(g.getTimestamp()),
            accel=np.array([a.x, a.y, a.z], dtype=np.float64),
            gyro=np.array([g.x, g.y, g.z], dtype=np.float64),
        ))
    return out


# ----------------------------------------------------------------------------- device part


_PRESETS = {
    "default": "DEFAULT", "density": "DENSITY", "accuracy": "ACCURACY", "fast_density": "FAST_DENSITY",
    "fast_accuracy": "FAST_ACCURACY", "robotics": "ROBOTICS", "high_detail": "HIGH_DETAIL",
}


def _build_pipeline(dai: Any, pipeline: Any, cfg: CameraConfig) -> tuple[Any, Any | None]:  # pragma: no cover
    """Create the device nodes; returns (synced colour/depth queue, IMU queue or None). Needs a device."""
    size = (cfg.width, cfg.height)
    cam = pipeline.create(dai.node.Camera).build(dai.CameraBoardSocket.CAM_A)
    color_out = cam.requestOutput(size, dai.ImgFrame.Type.RGB888i, dai.ImgResizeMode.CROP, cfg.fps,
                                  cfg.undistort)
    if cfg.depth == "aligned":
        left = pipeline.create(dai.node.Camera).build(dai.CameraBoardSocket.CAM_B)
        right = pipeline.create(dai.node.Camera).build(dai.CameraBoardSocket.CAM_C)
        stereo = pipeline.create(dai.node.StereoDepth)
        stereo.setDefaultProfilePreset(getattr(dai.node.StereoDepth.PresetMode, _PRESETS[cfg.stereo_preset]))
        stereo.setLeftRightCheck(cfg.left_right_check)
        stereo.setSubpixel(cfg.subpixel)
        stereo.setExtendedDisparity(cfg.extended_disparity)
        mono = (cfg.stereo_width, cfg.stereo_height)
        left.requestOutput(mono, fps=cfg.fps).link(stereo.left)
        right.requestOutput(mono, fps=cfg.fps).link(stereo.right)
        color_out.link(stereo.inputAlignTo)  # depth reprojected onto the colour frame, same size
        sync = pipeline.create(dai.node.Sync)
        sync.setSyncThreshold(datetime.timedelta(seconds=0.5 / cfg.fps))
        color_out.link(sync.inputs["rgb"])
        stereo.depth.link(sync.inputs["depth"])
        q = sync.out.createOutputQueue(maxSize=cfg.queue_size, blocking=False)
    else:
        q = color_out.createOutputQueue(maxSize=cfg.queue_size, blocking=False)
    imu_q = None
    if cfg.imu:
        imu = pipeline.create(dai.node.IMU)
        imu.enableIMUSensor([dai.IMUSensor.ACCELEROMETER_RAW, dai.IMUSensor.GYROSCOPE_RAW], cfg.imu_rate_hz)
        imu.setBatchReportThreshold(1)
        imu.setMaxBatchReports(10)
        imu_q = imu.out.createOutputQueue(maxSize=50, blocking=False)
    return q, imu_q


class OakSource:
    """Live OAK-D RGB-D frames as a `StreamSource`.

    Construction only discovers the device (fails fast with `OakNotFoundError`);
    iterating connects, starts the pipeline and yields `RgbdFrame`s until the iterator is
    closed (the pipeline and device are closed with it). IMU samples (if enabled) collect
    in `imu` (a bounded deque; oldest dropped). `strict=False` counts and skips bad frames
    (`stats.skipped`); `strict=True` raises.
    """

    def __init__(self, cfg: CameraConfig, strict: bool = False) -> None:
        self.cfg = cfg
        self.strict = strict
        self.stats = StreamStats()
        self.device_info = find_device(cfg)
        self.name = f"oak:{_info_id(self.device_info) or _info_name(self.device_info)}"
        self.imu: deque[ImuSample] = deque(maxlen=4096)
        self.K: NDArray[np.float64] | None = None

    def frame_count(self) -> int:
        """0: a live source has no known length."""
        return 0

    def _skip(self, reason: str, detail: str) -> None:
        if self.strict:
            raise StreamError(f"{self.name}: {reason}: {detail}")
        self.stats.skip(reason)

    def __iter__(self) -> Iterator[Message]:  # pragma: no cover - needs a device
        dai = import_depthai()
        cfg = self.cfg
        try:
            device = dai.Device(self.device_info)
        except RuntimeError as exc:
            raise OakNotFoundError(f"could not open OAK device {self.name}: {exc}") from exc
        with device, dai.Pipeline(device) as pipeline:
            q, imu_q = _build_pipeline(dai, pipeline, cfg)
            self.K = intrinsics_from_calibration(device.readCalibration(), cfg.width, cfg.height)
            pipeline.start()
            clock = HostClock.measure(cfg.clock)
            log.info("%s started: %dx%d @ %g fps, depth %s, clock %s", self.name, cfg.width, cfg.height,
                     cfg.fps, cfg.depth, cfg.clock)
            yield from self.frames_from_queues(pipeline.isRunning, q, imu_q, clock)

    def frames_from_queues(self, running: Callable[[], bool], q: Any, imu_q: Any | None,
                           clock: HostClock) -> Iterator[RgbdFrame]:
        """The receive loop over the pipeline's output queues (device-free; tested with host frames).

        `q.get(timedelta)` returns a `dai.MessageGroup` {"rgb", "depth"} (or a colour
        `ImgFrame` when depth is off) or None on timeout. Raises StreamError when no frame
        arrives for `first_frame_timeout_s` (before the first) / `frame_timeout_s` (after).
        """
        cfg = self.cfg
        index = 0
        last_t: int | None = None
        waited_since = time.monotonic()
        K_checked = False
        while running():
            if imu_q is not None:
                for m in imu_q.tryGetAll():
                    self.imu.extend(imu_samples_from_dai(m, clock))
            msg = q.get(datetime.timedelta(milliseconds=100))
            if msg is None:
                limit = cfg.first_frame_timeout_s if index == 0 else cfg.frame_timeout_s
                if time.monotonic() - waited_since > limit:
                    raise StreamError(f"{self.name}: no frame for {limit:g} s (device stalled or unplugged)")
                continue
            waited_since = time.monotonic()
            try:
                color, depth = (msg["rgb"], msg["depth"]) if cfg.depth == "aligned" else (msg, None)
                frame = rgbd_from_dai(color, depth, clock, self.K, index, cfg.frame_id, cfg.timestamp_at,
                                      cfg.jpeg_quality)
            except (StreamError, KeyError, RuntimeError) as exc:
                self._skip("bad frame", str(exc))
                continue
            if last_t is not None and frame.t_ns <= last_t:
                self._skip("timestamp not increasing", f"{frame.t_ns} ns after {last_t} ns")
                continue
            if not K_checked and self.K is not None:
                K_checked = True
                if not np.allclose(frame.K, self.K, rtol=0.02):
                    log.warning("%s: colour intrinsics of the frames %s differ from the scaled EEPROM calibration "
                                "%s; using the frames' (they follow the sensor mode's crop)", self.name,
                                np.round(frame.K, 2).tolist(), np.round(self.K, 2).tolist())
            last_t = frame.t_ns
            index += 1
            self.stats.messages += 1
            yield frame
