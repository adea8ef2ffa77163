"""Every setting declared once (`base/settings.py`): each field of each settings class has a typed
default and a description that stands alone, a unit where it is a physical quantity and a range
or choices where it is a number; validation comes from the declaration (no hand-written check
restates a declared range); every settings class is reachable from a configuration file, presets
restate no code default, `litevloc config show` prints the nested tree and says where a value
came from, and the generated docs are current."""

from __future__ import annotations

import ast
import dataclasses
import inspect
import math
import subprocess
import sys
import textwrap
import typing
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from litevloc.base.loader import ConfigError, from_mapping, load_yaml
from litevloc.base.settings import SettingError, Settings, section, setting, spec_of
from litevloc.config import PRESETS_DIR, preset_names
from litevloc.config.describe import (
    DEFAULT,
    OVERRIDE,
    choices_of,
    description_problems,
    load_with_origins,
    settings,
    settings_classes,
    standalone_problem,
)
from litevloc.config.schema import LiteVLocConfig

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("base", "config", "hw", "sim", "models", "pipelines", "runtime", "cli", "experiments")


def test_every_field_is_declared_with_a_description_that_stands_alone() -> None:
    problems = [p for cls in settings_classes() for p in description_problems(cls)]
    assert problems == []


@pytest.mark.parametrize(("text", "ok"), [
    ("a node is reached within this distance", True),
    ("... or turned this far", False),
    ("and within this rotation", False),
    ("the depth-squared term of that bound", False),
    ("keyframes this close (m) ...", False),
    ("a step turning faster than this is a jump too", False),
    ("", False),
])
def test_a_description_that_continues_another_is_caught(text: str, ok: bool) -> None:
    assert (standalone_problem(text) is None) == ok


# name endings that say a field is a physical quantity, so its declaration needs a unit
UNIT_SUFFIXES = ("_m", "_deg", "_rad", "_s", "_ms", "_px", "_hz", "_mib", "_m2", "_mps", "_dps")


def _numeric(tp: Any) -> bool:
    if tp in (int, float):
        return True
    return any(_numeric(a) for a in typing.get_args(tp) if a is not type(None) and a is not Ellipsis)


def test_every_physical_quantity_has_a_unit() -> None:
    missing = [f"{cls.__name__}.{f.name}" for cls in settings_classes() for f in dataclasses.fields(cls)
               if f.name.lower().endswith(UNIT_SUFFIXES) and (s := spec_of(f)) is not None and not s.is_section
               and not s.unit]
    assert missing == []


def test_every_number_has_a_range_and_every_literal_its_choices() -> None:
    missing = []
    for cls in settings_classes():
        hints = typing.get_type_hints(cls)
        for f in dataclasses.fields(cls):
            s = spec_of(f)
            if s is None or s.is_section or choices_of(hints[f.name]) or not _numeric(hints[f.name]):
                continue
            if not s.has_range:
                missing.append(f"{cls.__name__}.{f.name}")
    assert missing == []


def _restated_ranges(cls: type) -> list[str]:
    """Comparisons in `cls.check_relations` of one field that has a bounded declared range with a
    constant: the declaration already checks those (a range that depends on another field, such as
    `imu_rate_hz` while `imu` is on, is declared unbounded and checked there)."""
    if "check_relations" not in vars(cls):
        return []
    ranged = {f.name for f in dataclasses.fields(cls) if (s := spec_of(f)) is not None
              and any(b is not None and math.isfinite(b) for b in (s.low, s.high))}
    tree = ast.parse(textwrap.dedent(inspect.getsource(vars(cls)["check_relations"])))

    def field_of(node: ast.AST) -> str | None:
        if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id == "self":
            return node.attr
        return None

    def constant(node: ast.AST) -> bool:
        return isinstance(node, ast.Constant) or (isinstance(node, ast.UnaryOp) and isinstance(node.operand,
                                                                                               ast.Constant))

    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Compare):
            operands = [node.left, *node.comparators]
            names = [n for n in map(field_of, operands) if n is not None]
            others = [o for o in operands if field_of(o) is None]
            if len(names) == 1 and names[0] in ranged and others and all(map(constant, others)):
                out.append(f"{cls.__name__}.{names[0]}: {ast.unparse(node)}")
    return out


def test_no_hand_written_check_restates_a_declared_range() -> None:
    assert [p for cls in settings_classes() for p in _restated_ranges(cls)] == []


@dataclasses.dataclass(frozen=True)
class _Inner(Settings):
    gap_s: float = setting(0.5, "longest gap between two messages", unit="s", low=0, low_open=True, high=10)
    mode: typing.Literal["a", "b"] = setting("a", "which of the two modes runs")
    sizes: tuple[int, ...] = setting((2, 3), "sizes of the levels", low=1)
    lo: float = setting(0.0, "lower end of the band", unit="m", low=-math.inf)
    hi: float = setting(1.0, "upper end of the band", unit="m", low=-math.inf)

    def check_relations(self) -> None:
        if not self.lo < self.hi:
            raise ValueError(f"need lo < hi, got {self.lo}, {self.hi}")


@dataclasses.dataclass(frozen=True)
class _Outer(Settings):
    inner: _Inner = section(_Inner, "the inner section")
    count: int | None = setting(None, "how many, or none", low=1)


@pytest.mark.parametrize(("data", "pattern"), [
    ({"inner": {"gap_s": 0}}, r"^'inner\.gap_s' in f\.yaml must be a finite number in \(0, 10\], got 0\.0$"),
    ({"inner": {"gap_s": 10.5}}, r"'inner\.gap_s' .* in \(0, 10\], got 10\.5"),
    ({"inner": {"sizes": [2, 0]}}, r"'inner\.sizes' .*an integer in \[1, inf\) \(each item\), got \(2, 0\)"),
    ({"count": 0}, r"'count' in f\.yaml must be an integer in \[1, inf\), got 0"),
    ({"inner": {"lo": 2.0}}, r"'inner' in f\.yaml: need lo < hi, got 2\.0, 1\.0"),
])
def test_a_value_outside_its_declaration_names_the_dotted_key_the_value_and_the_range(
        data: dict[str, Any], pattern: str) -> None:
    with pytest.raises(ConfigError, match=pattern):
        from_mapping(_Outer, data, "f.yaml")
    assert from_mapping(_Outer, {"inner": {"gap_s": 10, "sizes": [1]}, "count": None}).inner.gap_s == 10.0


def test_the_declaration_also_checks_a_settings_class_built_in_code() -> None:
    with pytest.raises(SettingError, match=r"gap_s must be a finite number in \(0, 10\], got -1") as e:
        _Inner(gap_s=-1)
    err = e.value
    assert isinstance(err, ValueError) and isinstance(err, SettingError) and (err.key, err.value) == ("gap_s", -1)
    with pytest.raises(SettingError, match=r"mode must be one of \['a', 'b'\], got 'c'"):
        _Inner(mode="c")  # type: ignore[arg-type]
    with pytest.raises(SettingError, match="finite"):
        _Inner(gap_s=float("nan"))
    _Inner(gap_s=np.float64(2.0), sizes=(np.int64(4),))  # numpy scalars are numbers


@dataclasses.dataclass(frozen=True)
class _Gate(Settings):
    max_px: float = setting(2.0, "largest error a pose may have (inf: no such gate)", unit="px", low=0, off=math.inf)


def test_an_infinite_off_value_is_allowed_in_code_and_nothing_else_infinite() -> None:
    assert _Gate(max_px=math.inf).max_px == math.inf
    for bad in (-math.inf, math.nan, -1.0):
        with pytest.raises(SettingError, match=r"max_px must be a finite number in inf or \[0, inf\)"):
            _Gate(max_px=bad)


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
    from litevloc.sim.spec import WorldSpec  # the world file is the other configuration file

    reachable = {cls.__name__ for cls in settings_classes() + settings_classes(WorldSpec)}
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


def _show(*args: str) -> str:
    exe = Path(sys.executable).with_name("litevloc")
    r = subprocess.run([str(exe), "config", "show", *args], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    return r.stdout


def test_config_show_through_the_console_script_flat() -> None:
    out = _show("mapping.keyframes", "--config", "7scenes", "--set", "mapping.keyframes.budget=30", "--flat")
    lines = {line.split(" = ")[0]: line for line in out.splitlines()}
    assert "[override]" in lines["mapping.keyframes.budget"] and " = 30 " in lines["mapping.keyframes.budget"]
    assert "[7scenes.yaml]" in lines["mapping.keyframes.cell_m"] and " = 0.1 m " in lines["mapping.keyframes.cell_m"]
    assert "(0, 1]" in lines["mapping.keyframes.coverage"]
    assert set(lines) == {f"mapping.keyframes.{f.name}" for f in
                          dataclasses.fields(LiteVLocConfig().mapping.keyframes)}


def test_config_show_prints_the_nested_tree() -> None:
    """Sections as `name:` with their description, each setting indented under its section with
    its value, unit, origin, range and description."""
    lines = _show("mapping", "--config", "7scenes").splitlines()
    assert lines[0].startswith("mapping:  # map building")
    kf = lines.index(next(line for line in lines if line.startswith("  keyframes:")))
    assert "# which frames become keyframes" in lines[kf]
    cell = next(line for line in lines if line.strip().startswith("cell_m = "))
    assert cell.startswith("    cell_m = 0.1 m ") and "[7scenes.yaml]" in cell and "(0, inf)" in cell
    assert cell.rstrip().endswith("ground-plane cell of the coverage count")
    pnp = next(i for i, line in enumerate(lines) if line.startswith("    pnp:"))
    assert lines[pnp + 1].startswith("      ")  # a section two levels down is indented twice
    whole = _show()
    assert whole.splitlines()[0].startswith("name = default ") and "\nzenoh:  # the Zenoh session\n" in whole


def test_the_generated_docs_are_current() -> None:
    r = subprocess.run([sys.executable, str(ROOT / "docs" / "generate.py"), "--check"], capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 0, r.stderr
