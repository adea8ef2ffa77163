"""Every setting defined once: each field of each settings class has a typed default and a
one-line description, every settings class is reachable from a configuration file, presets
restate no code default, `litevloc config show` says where a value came from, and the
generated docs are current."""

from __future__ import annotations

import ast
import dataclasses
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from litevloc.base.loader import load_yaml
from litevloc.config import PRESETS_DIR, preset_names
from litevloc.config.describe import (
    DEFAULT,
    OVERRIDE,
    description_problems,
    field_descriptions,
    load_with_origins,
    settings,
    settings_classes,
)
from litevloc.config.schema import LiteVLocConfig

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("base", "config", "hw", "sim", "models", "pipelines", "runtime", "cli", "experiments")


def test_every_field_of_every_settings_class_has_a_one_line_description() -> None:
    problems = [p for cls in settings_classes() for p in description_problems(cls)]
    assert problems == []


@dataclasses.dataclass(frozen=True)
class _Example:
    # described
    a: int = 1
    b: int = 2  # a trailing comment is not a description
    # the first line of a block
    # and a second line: a block is not a one-line description
    c: int = 3

    # described after a blank line
    d: int = 4
    e: int = 5


def test_the_description_reader_accepts_exactly_one_comment_line_above_the_field() -> None:
    assert field_descriptions(_Example) == {"a": "described", "d": "described after a blank line"}
    problems = description_problems(_Example)
    assert [p.split(":")[0] for p in problems] == ["_Example.b", "_Example.c", "_Example.e"]
    assert "2 comment lines" in problems[1]


def _settings_class_names() -> dict[str, str]:
    """{class name: file} of every dataclass named *Params or *Config in the library packages."""
    out = {}
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text())):
                if (isinstance(node, ast.ClassDef) and node.name.endswith(("Params", "Config"))
                        and any("dataclass" in ast.unparse(d) for d in node.decorator_list)):
                    out[node.name] = str(path.relative_to(ROOT))
    return out


def test_every_settings_class_is_reachable_from_a_configuration_file() -> None:
    defined = _settings_class_names()
    reachable = {cls.__name__ for cls in settings_classes()}
    assert "MergeParams" in defined and "LiteVLocConfig" in reachable
    unreachable = {name: path for name, path in defined.items() if name not in reachable}
    assert unreachable == {}


def _leaves(data: Any, prefix: str = "") -> dict[str, Any]:
    if isinstance(data, dict):
        out: dict[str, Any] = {}
        for k, v in data.items():
            out.update(_leaves(v, f"{prefix}.{k}" if prefix else str(k)))
        return out
    return {prefix: data}


def _at(cfg: Any, key: str) -> Any:
    """The value at a dotted key; a key below a null section has none (it differs from any)."""
    for part in key.split("."):
        if cfg is None:
            return _NONE
        cfg = getattr(cfg, part)
    return cfg


_NONE = object()


@pytest.mark.parametrize("preset", preset_names())
def test_no_preset_restates_a_code_default(preset: str) -> None:
    """A preset holds only what differs for its sensor, data or deployment."""
    path = PRESETS_DIR / f"{preset}.yaml"
    effective, default = load_with_origins(path).config, LiteVLocConfig()
    restated = sorted(key for key in _leaves(load_yaml(path)) if _at(effective, key) == _at(default, key))
    assert restated == []


def test_a_preset_that_restates_a_default_is_caught(tmp_path: Path) -> None:
    p = tmp_path / "restating.yaml"
    p.write_text("name: mine\nreplay: {rate: 1.0}\nmapping: {keyframes: {budget: 12}}\n")
    effective, default = load_with_origins(p).config, LiteVLocConfig()
    assert [k for k in _leaves(load_yaml(p)) if _at(effective, k) == _at(default, k)] == ["replay.rate"]


def test_config_show_says_where_each_value_came_from(tmp_path: Path) -> None:
    p = tmp_path / "mine.yaml"
    p.write_text("mapping: {keyframes: {cell_m: 0.4}}\n")
    rows = {r.key: r for r in settings(load_with_origins(p, ["mapping.keyframes.budget=9"]))}
    assert (rows["mapping.keyframes.cell_m"].value, rows["mapping.keyframes.cell_m"].origin) == (0.4, "mine.yaml")
    assert (rows["mapping.keyframes.budget"].value, rows["mapping.keyframes.budget"].origin) == (9, OVERRIDE)
    assert rows["mapping.keyframes.coverage"].origin == DEFAULT
    assert rows["mapping.keyframes.cell_m"].description.startswith("ground-plane cell")
    assert len(rows) == len(settings(load_with_origins("default")))


def test_config_show_through_the_console_script() -> None:
    exe = Path(sys.executable).with_name("litevloc")
    r = subprocess.run([str(exe), "config", "show", "mapping.keyframes", "--config", "7scenes",
                        "--set", "mapping.keyframes.budget=30"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    lines = {line.split(" = ")[0]: line for line in r.stdout.splitlines()}
    assert "[override]" in lines["mapping.keyframes.budget"] and " = 30 " in lines["mapping.keyframes.budget"]
    assert "[7scenes.yaml]" in lines["mapping.keyframes.cell_m"]
    assert set(lines) == {f"mapping.keyframes.{f.name}" for f in
                          dataclasses.fields(LiteVLocConfig().mapping.keyframes)}


def test_the_generated_docs_are_current() -> None:
    r = subprocess.run([sys.executable, str(ROOT / "docs" / "generate.py"), "--check"], capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 0, r.stderr
