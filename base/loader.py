"""Strict YAML -> frozen dataclass loading.

Every configuration object in LiteVLoc is a frozen dataclass. `from_mapping` builds one
from a plain mapping (as `yaml.safe_load` returns it) and rejects unknown keys, missing
required keys and wrong types with a `ConfigError` that names the dotted key and the
file. Supported field types: bool, int, float, str, `Path`, `Literal[...]`, `X | None`,
`tuple[X, ...]`, `tuple[X, Y]`, nested dataclasses. Defaults live on the dataclasses
(one place for defaults, declared with `litevloc.base.settings.setting`, which also
validates them); YAML files only override.
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Literal, TypeVar, get_args, get_origin, get_type_hints

import yaml

from litevloc.base.errors import LiteVLocError
from litevloc.base.settings import SettingError

T = TypeVar("T")


class ConfigError(LiteVLocError, ValueError):
    """A configuration file or override is invalid; the message names the key and file."""


def _where(path: str, source: str | None) -> str:
    return f"'{path}'" + (f" in {source}" if source else "")


def _convert(value: Any, tp: Any, path: str, source: str | None) -> Any:
    origin = get_origin(tp)
    if tp is Any:
        return value
    if origin in (typing.Union, types.UnionType):
        args = get_args(tp)
        if value is None:
            if type(None) in args:
                return None
            raise ConfigError(f"{_where(path, source)} must not be null")
        errors = []
        for arg in args:
            if arg is type(None):
                continue
            try:
                return _convert(value, arg, path, source)
            except ConfigError as exc:
                errors.append(str(exc))
        raise ConfigError(errors[0] if len(errors) == 1 else f"{_where(path, source)}: " + "; ".join(errors))
    if origin is Literal:
        allowed = get_args(tp)
        if value not in allowed:
            raise ConfigError(f"{_where(path, source)} must be one of {list(allowed)}, got {value!r}")
        return value
    if origin is tuple:
        args = get_args(tp)
        if not isinstance(value, list | tuple):
            raise ConfigError(f"{_where(path, source)} must be a list, got {type(value).__name__}")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_convert(v, args[0], f"{path}[{i}]", source) for i, v in enumerate(value))
        if len(value) != len(args):
            raise ConfigError(f"{_where(path, source)} must have {len(args)} items, got {len(value)}")
        return tuple(_convert(v, a, f"{path}[{i}]", source) for i, (v, a) in enumerate(zip(value, args, strict=True)))
    if dataclasses.is_dataclass(tp) and isinstance(tp, type):
        if isinstance(value, tp):
            return value
        if not isinstance(value, Mapping):
            raise ConfigError(f"{_where(path, source)} must be a mapping, got {type(value).__name__}")
        return _build(tp, value, path, source)
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{_where(path, source)} must be true/false, got {value!r}")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{_where(path, source)} must be an integer, got {value!r}")
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ConfigError(f"{_where(path, source)} must be a number, got {value!r}")
        if not math.isfinite(value):  # NaN/inf pass most `>`/`<` checks silently
            raise ConfigError(f"{_where(path, source)} must be a finite number, got {value!r}")
        return float(value)
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"{_where(path, source)} must be a string, got {value!r}")
        return value
    if tp is Path:
        if not isinstance(value, str | Path):
            raise ConfigError(f"{_where(path, source)} must be a path string, got {value!r}")
        return Path(value)
    raise ConfigError(f"{_where(path, source)}: unsupported field type {tp!r}")  # pragma: no cover


def _with_section_defaults(field: dataclasses.Field[Any], value: Mapping[str, Any]) -> Mapping[str, Any]:
    """A partial mapping for a nested section keeps the section's DEFAULT values for the keys it
    does not give (the parent's default instance, which may differ from the section class's own
    defaults, and may be the only source of required keys such as level thresholds)."""
    if field.default_factory is not dataclasses.MISSING:
        default = field.default_factory()
    elif field.default is not dataclasses.MISSING:
        default = field.default
    else:
        return value
    if default is None or not dataclasses.is_dataclass(default):
        return value
    merged = {f.name: getattr(default, f.name) for f in dataclasses.fields(default) if f.init}
    merged.update(value)
    return merged


def _build(cls: type[T], data: Mapping[str, Any], prefix: str, source: str | None) -> T:
    hints = get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}  # type: ignore[arg-type]
    unknown = sorted(set(data) - set(fields))
    if unknown:
        key = f"{prefix}.{unknown[0]}" if prefix else str(unknown[0])
        raise ConfigError(
            f"unknown key {_where(key, source)}; allowed keys here: {sorted(fields)}"
        )
    kwargs: dict[str, Any] = {}
    for name, field in fields.items():
        key = f"{prefix}.{name}" if prefix else name
        if name in data:
            value = data[name]
            if isinstance(value, Mapping) and dataclasses.is_dataclass(hints[name]):
                value = _with_section_defaults(field, value)
            kwargs[name] = _convert(value, hints[name], key, source)
        elif field.default is dataclasses.MISSING and field.default_factory is dataclasses.MISSING:
            raise ConfigError(f"missing required key {_where(key, source)}")
    try:
        return cls(**kwargs)
    except SettingError as exc:  # a field outside its declaration
        key = f"{prefix}.{exc.key}" if prefix else exc.key
        raise ConfigError(f"{_where(key, source)} must be {exc.allowed}, got {exc.value!r}") from exc
    except (ValueError, TypeError) as exc:  # a rule between fields (`check_relations`)
        raise ConfigError(f"{_where(prefix or cls.__name__, source)}: {exc}") from exc


def from_mapping(cls: type[T], data: Mapping[str, Any] | None, source: str | None = None) -> T:
    """Build dataclass `cls` from a mapping, strictly (unknown keys and bad types raise)."""
    if data is None:
        data = {}
    if not isinstance(data, Mapping):
        raise ConfigError(f"top level{' of ' + source if source else ''} must be a mapping")
    return _build(cls, data, "", source)


def load_yaml(path: str | Path) -> dict[str, Any]:
    """Read a YAML mapping with `yaml.safe_load`; errors name the file."""
    p = Path(path)
    if not p.is_file():
        raise ConfigError(f"config file not found: {p}")
    try:
        data = yaml.safe_load(p.read_text(encoding="utf-8"))
    except yaml.YAMLError as exc:
        raise ConfigError(f"invalid YAML in {p}: {exc}") from exc
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ConfigError(f"top level of {p} must be a mapping, got {type(data).__name__}")
    return data


def apply_override(data: dict[str, Any], assignment: str) -> dict[str, Any]:
    """Apply one `dotted.key=value` override (value parsed as YAML) to a nested mapping.

    Returns a new mapping; the key must exist in the schema, which `from_mapping` checks.
    """
    if "=" not in assignment:
        raise ConfigError(f"override {assignment!r} must look like section.key=value")
    key, raw = assignment.split("=", 1)
    parts = [p for p in key.strip().split(".") if p]
    if not parts:
        raise ConfigError(f"override {assignment!r} has an empty key")
    try:
        value = yaml.safe_load(raw)
    except yaml.YAMLError as exc:
        raise ConfigError(f"override {assignment!r}: value is not valid YAML: {exc}") from exc
    out: dict[str, Any] = dict(data)
    node = out
    for part in parts[:-1]:
        child = node.get(part)
        child = dict(child) if isinstance(child, Mapping) else {}
        node[part] = child
        node = child
    node[parts[-1]] = value
    return out
