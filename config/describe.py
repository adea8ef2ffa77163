"""Every setting with its type, default, unit, range, description and origin (`litevloc config
show`, `docs/parameters.md`).

A setting is declared once, in its settings class (`base/params/*.py`, `config/schema.py`), with
`litevloc.base.settings.setting`:

    cell_m: float = setting(0.5, "ground-plane cell of the coverage count", unit="m", low=0, low_open=True)

`walk` goes through the configuration tree, yielding each section and each leaf with its
declaration and where its effective value came from: the code default, the preset or YAML file,
or a `--set` override. `litevloc.config.render` prints them.
"""

from __future__ import annotations

import dataclasses
import types
import typing
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any, Literal

from litevloc.base.loader import apply_override, from_mapping, load_yaml
from litevloc.base.settings import Spec, spec_of
from litevloc.config.schema import LiteVLocConfig

DEFAULT = "default"
OVERRIDE = "override"


@dataclasses.dataclass(frozen=True)
class Setting:
    """One leaf of the configuration tree."""

    # dotted key as written in YAML and `--set`, e.g. mapping.keyframes.cell_m
    key: str
    # the field's annotation as written in the source
    type: str
    # effective value
    value: Any
    # the code default at this place in the tree (a section's default may differ from its class's)
    default: Any
    # the declared description ("" when it has none)
    description: str
    # "default", the YAML file's name, or "override"
    origin: str
    # unit of a physical quantity ("" for counts, ratios, switches and names)
    unit: str = ""
    # what the declaration allows: a range such as `(0, inf)`, the choices `a | b`, or ""
    allowed: str = ""


@dataclasses.dataclass(frozen=True)
class Section:
    """One section of the configuration tree (a nested settings class)."""

    # dotted key, e.g. mapping.keyframes
    key: str
    # the section's declared description
    description: str


@dataclasses.dataclass(frozen=True)
class ConfigSources:
    """A configuration with the raw mappings it was built from (to tell where values came from)."""

    config: LiteVLocConfig
    # the preset or YAML file
    path: Path
    # what the file holds (`yaml.safe_load`)
    file_data: Mapping[str, Any]
    # what the `--set` overrides hold, as one nested mapping
    override_data: Mapping[str, Any]


def load_with_origins(name_or_path: str | Path | None = None, overrides: Sequence[str] = ()) -> ConfigSources:
    """`load_config`, keeping the file's and the overrides' mappings (same errors)."""
    from litevloc.config import resolve_config_path

    path = resolve_config_path("default" if name_or_path is None else name_or_path)
    file_data = load_yaml(path)
    data: dict[str, Any] = dict(file_data)
    override_data: dict[str, Any] = {}
    for ov in overrides:
        data = apply_override(data, ov)
        override_data = apply_override(override_data, ov)
    source = str(path) + (f" (with overrides {list(overrides)})" if overrides else "")
    return ConfigSources(from_mapping(LiteVLocConfig, data, source), path, file_data, override_data)


def declaration(cls: type, name: str) -> Spec:
    """The declaration of field `name` of settings class `cls` (`base/settings.py`)."""
    f = {f.name: f for f in dataclasses.fields(cls)}[name]
    spec = spec_of(f)
    if spec is None:  # tests/config/test_settings.py keeps every reachable field declared
        raise TypeError(f"{cls.__name__}.{name} is not declared with `setting` or `section`")
    return spec


def choices_of(tp: Any) -> tuple[Any, ...]:
    """The choices a `Literal` annotation (also inside `X | None` or `tuple[X, ...]`) allows; () if none."""
    if typing.get_origin(tp) is Literal:
        return typing.get_args(tp)
    for arg in typing.get_args(tp):
        if found := choices_of(arg):
            return found
    return ()


def allowed_text(cls: type, name: str) -> str:
    """What a field allows, as printed: its range (`(0, inf)`), its choices, or ""."""
    choices = choices_of(typing.get_type_hints(cls)[name])
    if choices:
        return " | ".join(map(str, choices))
    return declaration(cls, name).range_text()


_CONTINUATIONS = ("and ", "or ", "then ", "but ", "nor ", "as does ", "as do ", "until ")
_REFERRING = ("that bound", "that count", "as above", "the above", "each such", "the line above")


def standalone_problem(text: str) -> str | None:
    """Why a description does not stand alone (it continues or refers to the one above it), else None."""
    t = text.strip()
    if not t:
        return "no description"
    if t.startswith(("...", "\u2026")) or t.endswith(("...", "\u2026")):
        return f"continues another description: {t!r}"
    if t.lower().startswith(_CONTINUATIONS):
        return f"starts as a continuation ({t.split()[0]!r}): {t!r}"
    if any(r in t.lower() for r in _REFERRING) or t.lower().rstrip(".").endswith((" too", " as well")):
        return f"refers to another description: {t!r}"
    return None


def description_problems(cls: type) -> list[str]:
    """Fields of `cls` without a declaration or with a description that does not stand alone,
    as 'Class.field: why'."""
    out = []
    for f in dataclasses.fields(cls):
        spec = spec_of(f)
        if spec is None:
            out.append(f"{cls.__name__}.{f.name}: not declared with `setting` or `section` (base/settings.py)")
        elif (why := standalone_problem(spec.description)) is not None:
            out.append(f"{cls.__name__}.{f.name}: {why}")
    return out


def _dataclass_of(tp: Any) -> type | None:
    """The dataclass a field type holds (`X`, `X | None`), else None."""
    if dataclasses.is_dataclass(tp) and isinstance(tp, type):
        return tp
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        for arg in typing.get_args(tp):
            if dataclasses.is_dataclass(arg) and isinstance(arg, type):
                return arg
    return None


def settings_classes(root: type = LiteVLocConfig) -> list[type]:
    """Every settings class reachable from `root` through its fields, root first."""
    seen: list[type] = []
    todo = [root]
    while todo:
        cls = todo.pop(0)
        if cls in seen:
            continue
        seen.append(cls)
        hints = typing.get_type_hints(cls)
        todo += [c for f in dataclasses.fields(cls) if (c := _dataclass_of(hints[f.name])) is not None]
    return seen


def _has(data: Mapping[str, Any], parts: Sequence[str]) -> bool:
    node: Any = data
    for p in parts:
        if not isinstance(node, Mapping) or p not in node:
            return False
        node = node[p]
    return True


def walk(loaded: ConfigSources) -> list[Setting | Section]:
    """Every section and leaf of the effective configuration, depth first in the order of the
    classes' fields (a section before its fields). A null section (`rgbd_calibration` unless a
    preset gives it) is one leaf."""
    return list(_walk(LiteVLocConfig, loaded.config, LiteVLocConfig(), (), loaded))


def settings(loaded: ConfigSources) -> list[Setting]:
    """Every leaf of the effective configuration, in the order of the classes' fields."""
    return [r for r in walk(loaded) if isinstance(r, Setting)]


def all_fields() -> list[Setting]:
    """Every field of every settings class at its place in the tree, with the code default as
    value (a null section's fields with their class defaults; `value` is `REQUIRED` where the
    class has none)."""
    empty = ConfigSources(LiteVLocConfig(), Path("-"), {}, {})
    return [r for r in _walk(LiteVLocConfig, LiteVLocConfig(), LiteVLocConfig(), (), empty, expand_null=True)
            if isinstance(r, Setting)]


class _Required:
    def __repr__(self) -> str:
        return "required"


REQUIRED: Any = _Required()


def _walk(cls: type, value: Any, default: Any, prefix: tuple[str, ...], loaded: ConfigSources,
          expand_null: bool = False) -> Iterator[Setting | Section]:
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        parts = (*prefix, f.name)
        if value is not None:
            v = getattr(value, f.name)
        elif f.default is not dataclasses.MISSING:
            v = f.default
        elif f.default_factory is not dataclasses.MISSING:
            v = f.default_factory()
        else:
            v = REQUIRED
        d = getattr(default, f.name) if dataclasses.is_dataclass(default) else v
        section = _dataclass_of(hints[f.name])
        if section is not None and (dataclasses.is_dataclass(v) or (v is None and expand_null)):
            yield Section(".".join(parts), declaration(cls, f.name).description)
            yield from _walk(section, v, d, parts, loaded, expand_null)
            continue
        if _has(loaded.override_data, parts):
            origin = OVERRIDE
        elif _has(loaded.file_data, parts):
            origin = loaded.path.name
        else:
            origin = DEFAULT
        spec = declaration(cls, f.name)
        yield Setting(".".join(parts), str(f.type), v, d, spec.description, origin, spec.unit,
                      allowed_text(cls, f.name))
