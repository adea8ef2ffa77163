"""A command that needs an extra the install lacks stops with one line naming it (exit 2); the
commands that need none still run. The robot installs no onnxruntime from LiteVLoc when it has
NVIDIA's GPU wheel, and never torch: both are hidden here by a package on PYTHONPATH that fails
to import, as a missing one does."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

from tests.conftest import litevloc_exe


def _without(tmp_path: Path, *packages: str) -> dict[str, str]:
    for name in packages:
        (tmp_path / name).mkdir()
        (tmp_path / name / "__init__.py").write_text(f'raise ImportError("No module named {name!r}")\n')
    return {**os.environ, "PYTHONPATH": str(tmp_path), "LITEVLOC_MODEL_CACHE": str(tmp_path / "models")}


def _run(env: dict[str, str], *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([litevloc_exe(), *args], capture_output=True, text=True, env=env, timeout=120)


def test_without_onnxruntime_a_command_that_runs_models_names_the_extras(tmp_path: Path) -> None:
    r = _run(_without(tmp_path, "onnxruntime"), "models", "warmup")
    assert r.returncode == 2, (r.stdout, r.stderr)
    [line] = r.stderr.strip().splitlines()
    assert "onnxruntime is not installed" in line and "litevloc[cpu]" in line and "onnxruntime-gpu" in line


def test_without_onnxruntime_help_info_and_the_model_list_still_run(tmp_path: Path) -> None:
    """(`models export` too: torch writes the ONNX files, onnxruntime only runs them.)"""
    env = _without(tmp_path, "onnxruntime")
    assert _run(env, "--help").returncode == 0
    info = _run(env, "info")
    assert info.returncode == 0 and "onnxruntime is not installed" in info.stdout, info.stderr
    assert _run(env, "models", "list").returncode == 0


def test_without_torch_export_names_the_export_extra(tmp_path: Path) -> None:
    r = _run(_without(tmp_path, "torch"), "models", "export")
    assert r.returncode == 2, (r.stdout, r.stderr)
    assert "[export] extra" in r.stderr.strip().splitlines()[-1]
