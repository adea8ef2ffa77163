"""Config files: any YAML text loads to a valid config or raises ConfigError, and a value that
loads is the value that was written (nothing coerced silently)."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from litevloc.base.loader import ConfigError
from litevloc.config import load_config
from litevloc.config.schema import LiteVLocConfig


def _leaves(obj: Any, prefix: tuple[str, ...] = ()) -> list[tuple[tuple[str, ...], Any]]:
    """Every scalar leaf of a configuration object, walked on its default values (nested
    sections may have no defaults of their own, e.g. diagnostics level thresholds)."""
    out = []
    for f in dataclasses.fields(obj):
        v = getattr(obj, f.name)
        if dataclasses.is_dataclass(v):
            out += _leaves(v, (*prefix, f.name))
        else:
            out.append(((*prefix, f.name), v))
    return out


LEAVES = _leaves(LiteVLocConfig())
scalars = st.one_of(st.none(), st.booleans(), st.integers(-10**6, 10**6), st.floats(allow_nan=True),
                    st.text(max_size=12), st.lists(st.floats(-10, 10), max_size=5))
values = st.recursive(scalars, lambda c: st.lists(c, max_size=3) | st.dictionaries(st.text(max_size=6), c, max_size=3),
                      max_leaves=6)


def _get(cfg: Any, path: tuple[str, ...]) -> Any:
    for k in path:
        cfg = getattr(cfg, k)
    return cfg


def _same(given_value: Any, loaded: Any) -> bool:
    if isinstance(loaded, tuple):
        return isinstance(given_value, list | tuple) and len(given_value) == len(loaded) and all(
            _same(a, b) for a, b in zip(given_value, loaded, strict=True))
    if isinstance(loaded, bool) or isinstance(given_value, bool):
        return given_value is loaded
    if isinstance(loaded, float) and not math.isfinite(loaded):
        return False  # NaN/inf parameters are refused (they slip through range checks)
    if isinstance(loaded, float) and isinstance(given_value, int | float):
        return float(given_value) == loaded
    return bool(given_value == loaded)


@settings(max_examples=150)
@given(st.text(max_size=300))
def test_random_text(tmp_path: Path, count_case: Any, text: str) -> None:
    count_case()
    p = tmp_path / "c.yaml"
    p.write_text(text, encoding="utf-8")
    try:
        cfg = load_config(str(p))
    except ConfigError:
        return
    assert isinstance(cfg, LiteVLocConfig)


@settings(max_examples=250)
@given(st.sampled_from(LEAVES), values)
def test_one_key_any_value(tmp_path: Path, count_case: Any, leaf: tuple[tuple[str, ...], Any], value: Any) -> None:
    count_case()
    path, _default = leaf
    doc: dict[str, Any] = {}
    d = doc
    for k in path[:-1]:
        d = d.setdefault(k, {})
    d[path[-1]] = value
    p = tmp_path / "c.yaml"
    p.write_text(yaml.safe_dump(doc), encoding="utf-8")
    try:
        cfg = load_config(str(p))
    except ConfigError:
        return
    got = _get(cfg, path)
    if isinstance(value, dict) or path[-1] in ("tls", "access_control", "extra"):
        return  # pass-through blocks / nested parameter mappings
    assert _same(value, got), f"{'.'.join(path)}: wrote {value!r}, loaded {got!r}"


@settings(max_examples=100)
@given(st.dictionaries(st.text(max_size=10), values, max_size=4))
def test_unknown_top_level_keys(tmp_path: Path, count_case: Any, doc: dict[str, Any]) -> None:
    count_case()
    p = tmp_path / "c.yaml"
    p.write_text(yaml.safe_dump(doc), encoding="utf-8")
    known = {f.name for f in dataclasses.fields(LiteVLocConfig)}
    try:
        load_config(str(p))
    except ConfigError:
        return
    assert set(doc) <= known  # an unknown key never loads


FLOAT_LEAVES = [p for p, d in LEAVES if isinstance(d, float)]


def test_non_finite_numbers_are_refused_everywhere(count_case: Any) -> None:
    """Regression (found by this fuzzing): ~80 float parameters accepted .nan / .inf."""
    for path in FLOAT_LEAVES:
        for v in (".nan", ".inf", "-.inf"):
            count_case()
            try:
                load_config("default", [f"{'.'.join(path)}={v}"])
            except ConfigError as exc:
                assert "finite" in str(exc) or "must" in str(exc)
            else:
                raise AssertionError(f"{'.'.join(path)}={v} loaded")
