"""A recording read in a child process (`runtime.recording_process`) gives exactly the messages
the in-process read gives, hands back its counters, ends its child, and fails clearly."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

from litevloc.cli.main import main
from litevloc.hw.messages import EncodedRgbdFrame, GroundTruthPose, Odometry, StreamError
from litevloc.hw.streams.mcap_io import McapSource
from litevloc.runtime.recording_process import RecordingReaderProcess
from litevloc.runtime.sources import service_messages

pytestmark = pytest.mark.shared_data


@pytest.fixture(scope="module")
def recording(seven_scenes_dir: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    rec = tmp_path_factory.mktemp("recording_process") / "s.mcap"
    assert main(["convert", str(seven_scenes_dir), str(rec), "--frames", "0:30:3", "--odometry-rate", "100"]) == 0
    return rec


def _same(a: object, b: object) -> bool:
    if type(a) is not type(b):
        return False
    if isinstance(a, Odometry) and isinstance(b, Odometry):
        return a.t_ns == b.t_ns and np.array_equal(a.T_odom_base, b.T_odom_base)
    if isinstance(a, EncodedRgbdFrame) and isinstance(b, EncodedRgbdFrame):
        return (a.t_ns == b.t_ns and a.index == b.index and a.color_data == b.color_data
                and np.array_equal(a.depth, b.depth, equal_nan=True) and np.array_equal(a.K, b.K))
    if isinstance(a, GroundTruthPose) and isinstance(b, GroundTruthPose):
        return a.t_ns == b.t_ns and np.array_equal(a.T_world_camera, b.T_world_camera)
    return False


@pytest.mark.timeout(120)
def test_the_child_gives_the_messages_the_in_process_read_gives(recording: Path) -> None:
    ref = McapSource(recording, strict=False)
    here = list(ref.messages(defer_color=True))
    src = McapSource(recording, strict=False)
    reader = service_messages(src, reader_process=True)
    assert isinstance(reader, RecordingReaderProcess)
    there = list(reader)
    assert len(there) == len(here) > 100
    assert all(_same(a, b) for a, b in zip(here, there, strict=True))
    assert {type(m) for m in there} == {Odometry, EncodedRgbdFrame, GroundTruthPose}
    assert src.stats.messages == ref.stats.messages > 0 and src.stats.skipped == ref.stats.skipped
    assert reader._proc is not None and not reader._proc.is_alive()
    with pytest.raises(RuntimeError, match="once"):
        list(reader)


@pytest.mark.timeout(120)
def test_an_abandoned_read_ends_the_child(recording: Path) -> None:
    reader = RecordingReaderProcess(McapSource(recording, strict=False), batch=4)
    it = iter(reader)
    first = [next(it) for _ in range(5)]
    assert len(first) == 5
    proc = reader._proc
    assert proc is not None and proc.is_alive()
    it.close()  # what a consumer that stops early (the service at SIGTERM, bench's time limit) does
    deadline = time.monotonic() + 10
    while proc.is_alive() and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not proc.is_alive()


@pytest.mark.timeout(120)
def test_a_recording_the_child_cannot_read_is_a_stream_error(recording: Path, tmp_path: Path) -> None:
    broken = tmp_path / "broken.mcap"
    broken.write_bytes(recording.read_bytes())
    src = McapSource(broken, strict=False)  # opened (summary read) while the file was whole
    data = broken.read_bytes()
    broken.write_bytes(data[: len(data) // 2])  # then cut: the child finds the damage
    with pytest.raises(StreamError):
        list(RecordingReaderProcess(src))


def test_a_strict_source_is_refused() -> None:
    class Strict:
        strict = True

    with pytest.raises(ValueError, match="non-strictly"):
        RecordingReaderProcess(Strict())  # type: ignore[arg-type]


def test_the_reader_child_loads_no_opencv() -> None:
    """What the spawned reader imports (the recording reader and the message types) leaves OpenCV
    unloaded: colour stays JPEG until the service decodes it, and cv2 is ~15 MB of the child's RSS."""
    import subprocess
    import sys

    code = ("import sys; import litevloc.runtime.recording_process, litevloc.hw.streams.mcap_io, "
            "litevloc.hw.messages; print('cv2' in sys.modules)")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.strip() == "False"
