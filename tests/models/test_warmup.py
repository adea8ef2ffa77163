"""`litevloc models warmup`: every configured session built, run at its largest shape and timed; a
missing model cache is a one-line user error naming `litevloc models export`."""

from __future__ import annotations

import json
from pathlib import Path

import onnxruntime as ort
import pytest

from litevloc.cli.main import main
from litevloc.models import ort as mort
from tests.models.test_providers import GPU, FakeSession

FAST = ["--set", "models.tensorrt.profile_max_keypoints=64", "--set", "localization.second_look.candidates=0",
        "--runs", "1"]


def test_warmup_builds_and_times_every_configured_model(model_cache: Path, tmp_path: Path,
                                                        capsys: pytest.CaptureFixture[str]) -> None:
    mort.clear_session_reports()
    out = tmp_path / "warm.json"
    assert main(["models", "warmup", "--cache", str(model_cache), *FAST, "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "aliked-n16-240x320-k512" in text and "lightglue-aliked-adaptive" in text and "effnet-gem" in text
    data = json.loads(out.read_text())
    rows = {r["role"]: r for r in data["models"]}
    assert set(rows) == {"extractor", "matcher", "vpr"}  # no second look: its extractor is not built
    assert rows["matcher"]["sessions"] == 19 and rows["matcher"]["providers"] == ["CPUExecutionProvider"]
    assert all(r["steady_ms"] > 0 and r["first_run_s"] > 0 for r in rows.values())
    assert data["state"] == "as_asked" and data["onnxruntime"]["version"] == ort.__version__


def test_warmup_reports_the_provider_used_and_where_engines_go(
    model_cache: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    cache = tmp_path / "models"
    cache.mkdir()
    for f in model_cache.iterdir():
        if f.is_file():
            (cache / f.name).symlink_to(f)
    monkeypatch.setattr(ort, "get_available_providers", lambda: list(GPU))
    monkeypatch.setattr(ort, "InferenceSession", FakeSession)
    mort.clear_session_reports()
    out = tmp_path / "warm.json"
    assert main(["models", "warmup", "--cache", str(cache), *FAST, "--set", "models.providers=[tensorrt, cuda]",
                 "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert f"TensorRT engines: {cache / 'trt-engines'}" in text and "WARNING" not in text
    data = json.loads(out.read_text())
    assert {r["providers"][0] for r in data["models"]} == {"TensorrtExecutionProvider"}
    mort.clear_session_reports()


def test_warmup_without_a_model_cache_is_a_user_error(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["models", "warmup", "--cache", str(tmp_path / "none")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "litevloc models export" in err[0]
