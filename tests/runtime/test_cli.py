from __future__ import annotations

import json
from pathlib import Path

import pytest

from litevloc.cli.main import main


def test_info(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["info", "--json", str(tmp_path / "i.json")]) == 0
    info = json.loads((tmp_path / "i.json").read_text())
    assert "CPUExecutionProvider" in info["onnxruntime_providers"] and "default" in info["presets"]


def test_convert_and_replay(seven_scenes_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "s.mcap"
    assert main(["convert", str(seven_scenes_dir), str(out), "--frames", "0:30", "--odometry-rate", "100",
                 "--json", str(tmp_path / "c.json")]) == 0
    conv = json.loads((tmp_path / "c.json").read_text())
    assert conv["frames"] == 30 and conv["ground_truth"] == 30
    assert conv["odometry"] == 97  # 29 frame intervals at 30 Hz = 0.9667 s -> 97 samples at 100 Hz
    assert main(["replay", str(out), "--rate", "0", "--json", str(tmp_path / "r.json")]) == 0
    rep = json.loads((tmp_path / "r.json").read_text())
    assert rep["frames"] == 30 and rep["odometry"] == 97 and rep["skipped"] == {}
    assert main(["replay", str(out), "--rate", "0", "--frames", "5:10", "--json", str(tmp_path / "r2.json")]) == 0
    assert json.loads((tmp_path / "r2.json").read_text())["frames"] == 5


def test_user_errors_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["replay", str(tmp_path / "missing.mcap")]) == 2
    assert "not found" in capsys.readouterr().err
    assert main(["convert", str(tmp_path), str(tmp_path / "x.mcap")]) == 2
    assert "not a 7-Scenes folder" in capsys.readouterr().err
    assert main(["replay", str(tmp_path), "--frames", "x:y"]) == 2
    assert "--frames" in capsys.readouterr().err
    assert main(["replay", str(tmp_path), "--config", "nope"]) == 2
    assert "unknown config" in capsys.readouterr().err


def test_a_replay_without_a_fused_pose_still_writes_its_output_and_says_why(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    """A run where fusion never started (no two agreeing fixes) leaves an empty TUM file, not the
    previous run's, and names the reasons."""
    import argparse

    import numpy as np

    from litevloc.cli import replay
    from litevloc.runtime.service.app import Recorder

    out = tmp_path / "fused.txt"
    out.write_text("0.0 1 2 3 0 0 0 1\n")  # an earlier run's poses
    rec = Recorder()
    status = {"last_fusion_reason": None, "last_vloc_reason": "not localized: no VPR candidate verified"}
    monkeypatch.setattr("litevloc.cli.run.run_service", lambda *a, **k: {
        "ok": True, "reason": "end of source", "status": status, "recorder": rec, "T_base_camera": np.eye(4)})
    assert replay.run_runtime(argparse.Namespace(rec=tmp_path / "r.mcap", rate=1.0, output=out, json=None)) == 0
    assert [ln for ln in out.read_text().splitlines() if not ln.startswith("#")] == []
    said = capsys.readouterr().out
    assert "0 fused poses (fusion: never started; last VLoc answer: not localized: no VPR candidate verified)" in said
