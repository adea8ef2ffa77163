"""Registry, manifest, cache location, `litevloc models export|list`, and no torch at run time."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from litevloc.base.params.models import ModelsConfig
from litevloc.cli.main import main
from litevloc.models.catalog import EXPORT_VERSION, spec_for
from litevloc.models.registry import (
    ModelError,
    default_cache_dir,
    load_extractor,
    load_matcher,
    load_place_recognizer,
    locate,
    read_manifest,
)


def test_default_cache_dir_precedence(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.delenv("LITEVLOC_MODEL_CACHE", raising=False)
    monkeypatch.delenv("XDG_CACHE_HOME", raising=False)
    assert default_cache_dir() == Path.home() / ".cache" / "litevloc" / "models"
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert default_cache_dir() == tmp_path / "xdg" / "litevloc" / "models"
    monkeypatch.setenv("LITEVLOC_MODEL_CACHE", str(tmp_path / "own"))
    assert default_cache_dir() == tmp_path / "own"


def test_missing_model_names_the_export_command(tmp_path: Path) -> None:
    cfg = ModelsConfig(cache_dir=str(tmp_path))
    for load, name in (
        (load_extractor, "aliked-n16"),
        (load_matcher, "lightglue"),
        (load_place_recognizer, "effnet-gem"),
    ):
        with pytest.raises(ModelError, match="litevloc models export"):
            load(name, cfg)  # type: ignore[operator]
    with pytest.raises(ModelError, match="cosplace-checkpoint"):
        load_place_recognizer("cosplace", cfg)
    with pytest.raises(ModelError, match="unknown"):
        load_extractor("superpoint", cfg)


def test_spec_ids() -> None:
    s = spec_for("aliked-n16-480x640-k1024")
    assert (s.kind, s.arch, s.input_hw, s.top_k) == ("extractor", "aliked-n16", (480, 640), 1024)
    assert spec_for("effnet-gem-240x320").input_hw == (240, 320)
    for bad in ("aliked-x16-240x320-k512", "aliked-n16-241x320-k512", "nope"):
        with pytest.raises(ValueError):
            spec_for(bad)


def _copy_cache(src: Path, dst: Path, model_id: str) -> None:
    dst.mkdir(parents=True, exist_ok=True)
    shutil.copy(src / f"{model_id}.onnx", dst / f"{model_id}.onnx")
    entry = read_manifest(src)["models"][model_id]
    (dst / "manifest.json").write_text(json.dumps({"format": 1, "models": {model_id: entry}}))


def test_mismatched_model_is_an_error(model_cache: Path, tmp_path: Path) -> None:
    mid = "aliked-t16-240x320-k512"
    cache = tmp_path / "c"
    _copy_cache(model_cache, cache, mid)
    cfg = ModelsConfig(cache_dir=str(cache), extractor="aliked-t16")
    path, entry = locate(mid, cfg)
    assert (
        entry["source"]["sha256"]
        and entry["opset"] == 19
        and entry["export_version"] == EXPORT_VERSION
    )
    load_extractor("aliked-t16", cfg)  # loads
    with open(path, "ab") as f:  # corrupt the file
        f.write(b"\0")
    with pytest.raises(ModelError, match=r"sha256.*litevloc models export"):
        locate(mid, cfg)
    _copy_cache(model_cache, cache, mid)
    m = json.loads((cache / "manifest.json").read_text())
    m["models"][mid]["export_version"] = EXPORT_VERSION - 1
    (cache / "manifest.json").write_text(json.dumps(m))
    with pytest.raises(ModelError, match=r"export_version.*--force"):
        locate(mid, cfg)
    (cache / "manifest.json").write_text("{not json")
    with pytest.raises(ModelError, match="manifest"):
        locate(mid, cfg)


def test_cli_export_is_idempotent_and_list(
    model_cache: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cache = tmp_path / "cli"
    mid = "aliked-t16-240x320-k512"
    args = [
        "models",
        "export",
        "--cache",
        str(cache),
        "--model",
        mid,
        "--json",
        str(tmp_path / "e.json"),
    ]
    assert main(args) == 0
    assert json.loads((tmp_path / "e.json").read_text())["models"] == {mid: "built"}
    assert main(args) == 0
    assert json.loads((tmp_path / "e.json").read_text())["models"] == {mid: "up-to-date"}
    assert main(["models", "list", "--cache", str(cache), "--json", str(tmp_path / "l.json")]) == 0
    rows = {r["id"]: r for r in json.loads((tmp_path / "l.json").read_text())["models"]}
    assert rows[mid]["status"] == "ok" and rows["lightglue-aliked"]["status"] == "missing"
    assert main(["models", "export", "--cache", str(cache), "--model", "bogus"]) == 2
    assert "unknown model id" in capsys.readouterr().err


def test_runtime_never_imports_torch(model_cache: Path) -> None:
    code = (
        "import sys\n"
        "from litevloc.base.params.models import ModelsConfig\n"
        "from litevloc.models.registry import load_extractor, load_matcher, load_place_recognizer\n"
        "import litevloc.cli.main as m\n"
        "m.build_parser()\n"
        f"cfg = ModelsConfig(cache_dir={str(model_cache)!r})\n"
        "load_extractor('aliked-n16', cfg); load_matcher('lightglue', cfg)\n"
        "load_place_recognizer('effnet-gem', cfg); load_extractor('sift', cfg)\n"
        "assert 'torch' not in sys.modules, 'torch was imported'\n"
        "assert not any(k.startswith('litevloc.models.export') for k in sys.modules)\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
