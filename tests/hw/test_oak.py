"""OAK-D driver: everything that needs no device, with depthai objects built on the host."""

from __future__ import annotations

import datetime
import time
from collections import deque
from pathlib import Path

import numpy as np
import pytest

from litevloc.base.loader import ConfigError, from_mapping
from litevloc.base.params.camera import CameraConfig
from litevloc.config import load_config
from litevloc.hw.messages import StreamError, StreamStats, decode_color
from litevloc.hw.oak import (
    HostClock,
    OakNotFoundError,
    OakSource,
    color_from_imgframe,
    find_device,
    imu_samples_from_dai,
    intrinsics_from_calibration,
    intrinsics_from_frame,
    rgbd_from_dai,
    timedelta_to_ns,
)

dai = pytest.importorskip("depthai")

K_1080 = [[1500.0, 0.0, 950.0], [0.0, 1500.0, 530.0], [0.0, 0.0, 1.0]]


def _device_present() -> bool:
    return bool(dai.Device.getAllAvailableDevices())


# ----------------------------------------------------------------------------- configuration


def test_preset_loads_with_camera_section() -> None:
    cfg = load_config("config/oak-d.yaml")
    assert cfg.source.kind == "oak-d"
    assert (cfg.camera.width, cfg.camera.height, cfg.camera.depth) == (640, 480, "aligned")
    assert load_config(None).camera == CameraConfig()


@pytest.mark.parametrize(
    ("data", "needle"),
    [
        ({"fps": 0}, "fps"),
        ({"width": 641}, "even"),
        ({"width": 8}, "width"),
        ({"depth": "raw"}, "depth"),
        ({"clock": "gps"}, "clock"),
        ({"jpeg_quality": 101}, "jpeg_quality"),
        ({"imu": True, "imu_rate_hz": 0}, "imu_rate_hz"),
        ({"discovery_timeout_s": 0}, "discovery_timeout_s"),
        ({"exposure": 3}, "unknown key"),
    ],
)
def test_camera_config_rejects_bad_values(data: dict, needle: str) -> None:
    with pytest.raises(ConfigError, match=needle):
        from_mapping(CameraConfig, data, "test.yaml")


# ----------------------------------------------------------------------------- discovery


class _Info:
    def __init__(self, device_id: str, name: str) -> None:
        self.deviceId = device_id
        self.name = name

    def getDeviceId(self) -> str:
        return self.deviceId


def test_find_device_picks_configured_id_or_first() -> None:
    infos = [_Info("18443010A1", "1.1"), _Info("19443010B2", "1.2")]
    assert find_device(CameraConfig(), lambda: infos, lambda: infos) is infos[0]
    assert find_device(CameraConfig(device_id="19443010B2"), lambda: infos, lambda: infos) is infos[1]
    assert find_device(CameraConfig(device_id="1.2"), lambda: infos, lambda: infos) is infos[1]
    with pytest.raises(OakNotFoundError, match=r"no OAK device found with id or name 'XYZ'.*18443010A1"):
        find_device(CameraConfig(device_id="XYZ", discovery_timeout_s=0.3), lambda: infos, lambda: infos)


def test_find_device_tells_a_busy_device() -> None:
    busy = [_Info("18443010A1", "1.1")]
    with pytest.raises(OakNotFoundError, match="18443010A1 is connected but not available"):
        find_device(CameraConfig(discovery_timeout_s=0.3), lambda: [], lambda: busy)


def test_find_device_polls_until_the_device_appears() -> None:
    calls = {"n": 0}

    def appears_late() -> list[_Info]:
        calls["n"] += 1
        return [_Info("A", "a")] if calls["n"] >= 3 else []

    assert find_device(CameraConfig(discovery_timeout_s=5.0), appears_late, list).deviceId == "A"
    assert calls["n"] == 3


def test_no_device_fails_fast_with_clear_message() -> None:
    if _device_present():
        pytest.skip("an OAK device is connected")
    t0 = time.monotonic()
    with pytest.raises(OakNotFoundError, match="no OAK device found"):
        OakSource(CameraConfig(discovery_timeout_s=1.0))
    assert time.monotonic() - t0 < 4.0  # never the ~11 s search of dai.Pipeline()


# ----------------------------------------------------------------------------- time


def test_timedelta_to_ns_is_exact() -> None:
    td = datetime.timedelta(days=2, seconds=3, microseconds=456789)
    assert timedelta_to_ns(td) == ((2 * 86400 + 3) * 1_000_000 + 456789) * 1000
    assert timedelta_to_ns(datetime.timedelta(microseconds=1)) == 1000


def test_depthai_clock_is_the_host_monotonic_clock() -> None:
    # The assumption HostClock rests on: dai.Clock.now() (steady_clock) == time.monotonic_ns().
    before = time.monotonic_ns()
    now = timedelta_to_ns(dai.Clock.now())
    after = time.monotonic_ns()
    assert before - 1000 <= now <= after + 1000


def test_host_clock_offsets() -> None:
    steady = datetime.timedelta(seconds=100, microseconds=5)
    assert HostClock.measure("monotonic").to_host_ns(steady) == 100_000_005_000
    rt = HostClock.measure("realtime")
    assert abs(rt.offset_ns - (time.time_ns() - time.monotonic_ns())) < 5_000_000
    # a depthai stamp of "now" maps to the wall clock now
    assert abs(rt.to_host_ns(dai.Clock.now()) - time.time_ns()) < 5_000_000
    assert rt.to_host_ns(steady) == 100_000_005_000 + rt.offset_ns


# ----------------------------------------------------------------------------- calibration


def _calibration() -> object:
    calib = dai.CalibrationHandler()
    calib.setCameraIntrinsics(dai.CameraBoardSocket.CAM_A, K_1080, 1920, 1080)
    return calib


def test_intrinsics_from_calibration_scale_to_output_size() -> None:
    K = intrinsics_from_calibration(_calibration(), 640, 360)
    np.testing.assert_allclose(K, np.array(K_1080) * [[1 / 3], [1 / 3], [1]], rtol=1e-6)
    K2 = intrinsics_from_calibration(_calibration(), 1920, 1080)
    np.testing.assert_allclose(K2, K_1080, rtol=1e-6)


def test_intrinsics_from_eeprom_json_round_trip(tmp_path: Path) -> None:
    path = tmp_path / "eeprom.json"
    _calibration().eepromToJsonFile(str(path))
    K = intrinsics_from_calibration(dai.CalibrationHandler(str(path)), 960, 540)
    np.testing.assert_allclose(K, np.array(K_1080) * [[0.5], [0.5], [1]], rtol=1e-6)


def test_intrinsics_missing_camera_is_a_clear_error() -> None:
    with pytest.raises(StreamError, match="no intrinsics for CAM_B"):
        intrinsics_from_calibration(_calibration(), 640, 400, socket="CAM_B")


def test_intrinsics_from_frame_transformation() -> None:
    tr = dai.ImgTransformation(1920, 1080, K_1080)
    tr.addScale(0.5, 0.5)
    f = dai.ImgFrame()
    f.setCvFrame(np.zeros((540, 960, 3), np.uint8), dai.ImgFrame.Type.RGB888i)
    assert intrinsics_from_frame(f) is None  # host frame without a transformation
    f.setTransformation(tr)
    np.testing.assert_allclose(intrinsics_from_frame(f), np.array(K_1080) * [[0.5], [0.5], [1]])


# ----------------------------------------------------------------------------- messages


def _color_frame(rgb: np.ndarray, steady_us: int, kind: str = "RGB888i") -> object:
    f = dai.ImgFrame()
    f.setCvFrame(np.ascontiguousarray(rgb[:, :, ::-1]), getattr(dai.ImgFrame.Type, kind))
    f.setTimestamp(datetime.timedelta(microseconds=steady_us))
    return f


def _depth_frame(mm: np.ndarray) -> object:
    d = dai.ImgFrame()
    d.setFrame(mm)
    d.setType(dai.ImgFrame.Type.RAW16)
    d.setWidth(mm.shape[1])
    d.setHeight(mm.shape[0])
    return d


@pytest.mark.parametrize("kind", ["RGB888i", "BGR888i"])
def test_color_conversion_gives_rgb(kind: str) -> None:
    rgb = np.random.default_rng(0).integers(0, 256, (6, 8, 3), dtype=np.uint8)
    out = color_from_imgframe(_color_frame(rgb, 0, kind))
    assert out.dtype == np.uint8 and out.flags["C_CONTIGUOUS"]
    np.testing.assert_array_equal(out, rgb)


def test_rgbd_from_dai_converts_depth_time_and_intrinsics() -> None:
    rng = np.random.default_rng(1)
    rgb = rng.integers(0, 256, (4, 6, 3), dtype=np.uint8)
    mm = rng.integers(0, 6000, (4, 6), dtype=np.uint16)
    mm[0, :3] = 0
    clock = HostClock("realtime", 1_700_000_000_000_000_000)
    K = np.array([[5.0, 0, 3], [0, 5.0, 2], [0, 0, 1]])
    frame = rgbd_from_dai(_color_frame(rgb, 2_500_001), _depth_frame(mm), clock, K, index=7, frame_id="oak")
    assert frame.t_ns == 2_500_001_000 + 1_700_000_000_000_000_000
    np.testing.assert_array_equal(frame.color, rgb)
    assert frame.depth is not None and frame.depth.dtype == np.float32
    assert np.isnan(frame.depth[0, :3]).all()
    valid = mm > 0
    np.testing.assert_array_equal(frame.depth[valid], mm[valid].astype(np.float32) / np.float32(1000.0))
    np.testing.assert_array_equal(frame.K, K)
    assert (frame.index, frame.frame_id, frame.color_jpeg) == (7, "oak", None)


def test_rgbd_from_dai_jpeg_round_trip_matches_replay() -> None:
    rgb = np.random.default_rng(2).integers(0, 256, (32, 48, 3), dtype=np.uint8)
    frame = rgbd_from_dai(_color_frame(rgb, 1), None, HostClock("monotonic", 0), np.eye(3), 0, jpeg_quality=90)
    assert frame.color_jpeg is not None and frame.depth is None
    # what the live run sees == what a recording of it decodes to
    np.testing.assert_array_equal(frame.color, decode_color(frame.color_jpeg, "test"))


def test_rgbd_from_dai_rejects_unaligned_depth_and_missing_K() -> None:
    rgb = np.zeros((4, 6, 3), np.uint8)
    clock = HostClock("monotonic", 0)
    with pytest.raises(StreamError, match="not aligned"):
        rgbd_from_dai(_color_frame(rgb, 1), _depth_frame(np.ones((2, 3), np.uint16)), clock, np.eye(3), 0)
    with pytest.raises(StreamError, match="no intrinsics"):
        rgbd_from_dai(_color_frame(rgb, 1), None, clock, None, 0)


def test_imu_packets_convert() -> None:
    pkt = dai.IMUPacket()
    data = dai.IMUData()
    data.packets = [pkt]
    samples = imu_samples_from_dai(data, HostClock("monotonic", 0))
    assert len(samples) == 1 and samples[0].accel.shape == (3,) and samples[0].gyro.shape == (3,)


# ----------------------------------------------------------------------------- receive loop


class _Queue:
    """Stands in for a `dai.MessageQueue`: hands out prepared messages, then None (timeouts)."""

    def __init__(self, msgs: list[object]) -> None:
        self.msgs = list(msgs)

    def get(self, timeout: datetime.timedelta) -> object | None:
        if self.msgs:
            return self.msgs.pop(0)
        time.sleep(min(timeout.total_seconds(), 0.01))
        return None


def _group(rgb: np.ndarray, mm: np.ndarray, steady_us: int) -> object:
    g = dai.MessageGroup()
    g["rgb"] = _color_frame(rgb, steady_us)
    g["depth"] = _depth_frame(mm)
    return g


def _source(**kw: object) -> OakSource:
    src = OakSource.__new__(OakSource)  # skip discovery: the loop needs no device
    src.cfg = CameraConfig(**kw)  # type: ignore[arg-type]
    src.strict = False
    src.stats = StreamStats()
    src.name = "oak:test"
    src.imu = deque()
    src.K = np.array([[5.0, 0, 3], [0, 5.0, 2], [0, 0, 1]])
    return src


def test_receive_loop_yields_frames_and_counts_skips() -> None:
    rgb = np.full((4, 6, 3), 7, np.uint8)
    mm = np.full((4, 6), 1500, np.uint16)
    msgs = [
        _group(rgb, mm, 1_000),
        _group(rgb, np.ones((2, 3), np.uint16), 2_000),  # depth not aligned -> skipped
        _group(rgb, mm, 3_000),
        _group(rgb, mm, 2_500),  # time going backwards -> skipped
    ]
    src = _source(jpeg_quality=0, frame_timeout_s=0.2)
    out = []
    with pytest.raises(StreamError, match=r"no frame for 0\.2 s"):
        for f in src.frames_from_queues(lambda: True, _Queue(msgs), None, HostClock("monotonic", 0)):
            out.append(f)
    assert [f.t_ns for f in out] == [1_000_000, 3_000_000]
    assert [f.index for f in out] == [0, 1]
    assert np.allclose(out[0].depth, 1.5)
    assert src.stats.skipped == {"bad frame": 1, "timestamp not increasing": 1}
    assert src.stats.messages == 2


def test_receive_loop_strict_raises_and_stops_when_pipeline_stops() -> None:
    rgb = np.zeros((4, 6, 3), np.uint8)
    src = _source(jpeg_quality=0)
    src.strict = True
    bad = [_group(rgb, np.ones((2, 3), np.uint16), 1)]
    with pytest.raises(StreamError, match="not aligned"):
        list(src.frames_from_queues(lambda: True, _Queue(bad), None, HostClock("monotonic", 0)))
    assert list(src.frames_from_queues(lambda: False, _Queue([]), None, HostClock("monotonic", 0))) == []
