"""VLoc in a child process (`runtime.service.vloc_process`): the same results as in a thread, clear
errors when the child cannot start or dies, and a clean end."""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path

import numpy as np
import pytest

from litevloc.cli.main import main
from litevloc.config import load_config
from litevloc.hw.messages import RgbdFrame
from litevloc.hw.streams.mcap_io import McapSource
from litevloc.runtime.service.vloc_process import VlocProcess, VlocProcessError, VlocWorkerSpec
from tests.conftest import HeldOut

from .zenoh_helpers import free_port

pytestmark = pytest.mark.shared_data


@pytest.fixture(scope="module")
def small_map(seven_scenes_held_out: HeldOut) -> tuple[Path, Path]:
    """(recording of held-out 7-Scenes query frames, the map of the mapping pass)."""
    return seven_scenes_held_out.queries, seven_scenes_held_out.map_dir


def _first_frame(rec: Path) -> RgbdFrame:
    frame = next(m for m in McapSource(rec) if isinstance(m, RgbdFrame))
    if frame.depth.dtype != np.float32:
        import dataclasses

        frame = dataclasses.replace(frame, depth=frame.depth.astype(np.float32))
    return frame


@pytest.mark.timeout(300)
def test_deterministic_replay_gives_the_same_trajectory_with_vloc_in_a_process(
        small_map: tuple[Path, Path], tmp_path: Path) -> None:
    rec, mp = small_map
    trajs = {}
    for placement in ("false", "true"):
        traj = tmp_path / f"fused_{placement}.txt"
        assert main(["replay", str(rec), "--frames", "0:12", "--config", "7scenes", "--map", str(mp), "-o", str(traj),
                     "--listen", f"tcp/127.0.0.1:{free_port()}", "--set", "runtime.mode=deterministic",
                     "--set", f"runtime.vloc_process={placement}"]) == 0
        trajs[placement] = traj.read_text()
    assert len(trajs["false"].splitlines()) > 100  # 12 frames 0.33 s apart, 100 Hz odometry
    assert trajs["true"] == trajs["false"]


@pytest.mark.timeout(180)
def test_the_child_answers_queries_and_a_dead_child_is_a_clear_error(small_map: tuple[Path, Path]) -> None:
    rec, mp = small_map
    cfg = load_config("7scenes")
    proc = VlocProcess(VlocWorkerSpec(cfg, mp))
    try:
        assert proc.pid is not None and proc.pid != os.getpid()
        res = proc(_first_frame(rec), None)
        assert res.accepted and res.T_map_camera is not None  # a held-out frame, global localization
        assert res.tracking_state  # the child's localizer state travels with the result
        assert proc.calls == 1
        report = proc.provider_report  # what the child's sessions run on, for the service's status
        assert report is not None and report.models and report.state.value == "as_asked"
        assert {u for m in report.models for u in m.used} == {"CPUExecutionProvider"}
        os.kill(proc.pid, signal.SIGKILL)
        with pytest.raises(VlocProcessError, match="died"):
            proc(_first_frame(rec), None)
        with pytest.raises(VlocProcessError, match="died"):  # and on every later call
            proc(_first_frame(rec), None)
    finally:
        proc.close()
    proc.close()  # idempotent


@pytest.mark.timeout(120)
def test_a_bad_map_is_the_same_user_error_before_anything_runs(tmp_path: Path) -> None:
    (tmp_path / "empty").mkdir()
    with pytest.raises(VlocProcessError, match="manifest"):
        VlocProcess(VlocWorkerSpec(load_config("default"), tmp_path / "empty"))


@pytest.mark.timeout(180)
def test_close_ends_the_child_and_signals_do_not(small_map: tuple[Path, Path]) -> None:
    _, mp = small_map
    proc = VlocProcess(VlocWorkerSpec(load_config("7scenes"), mp))
    pid = proc.pid
    assert pid is not None
    os.kill(pid, signal.SIGINT)  # Ctrl-C reaches the process group: the parent decides when VLoc ends
    os.kill(pid, signal.SIGTERM)
    time.sleep(1.0)
    assert proc._proc.is_alive()
    proc.close()
    assert not proc._proc.is_alive() and proc._proc.exitcode == 0
