"""Every setting with its type, default, description and origin (`litevloc config show`,
`docs/parameters.md`).

A setting's description is the one `#` comment line directly above its field in the settings
class (`base/params/*.py`, `config/schema.py`):

    # cell of the coverage grid that one keyframe covers (m)
    cell_m: float = 0.5

`field_descriptions` reads them from the source, so the description lives in one place, beside
the typed default. `settings` walks the configuration tree and says where each effective value
came from: the code default, the preset or YAML file, or a `--set` override.
"""

from __future__ import annotations

import ast
import dataclasses
import functools
import inspect
import textwrap
import types
import typing
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

from litevloc.base.loader import apply_override, from_mapping, load_yaml
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
    # the one-line comment above the field ("" when it has none)
    description: str
    # "default", the YAML file's name, or "override"
    origin: str


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


def field_descriptions(cls: type) -> dict[str, str]:
    """{field name: the one `#` line directly above it} for a dataclass, from its source.

    A field without such a line, or with a comment block of several lines above it, is left
    out (`description_problems` names them)."""
    return {name: text for name, (text, n_lines) in _comments(cls).items() if n_lines == 1}


def description_problems(cls: type) -> list[str]:
    """Fields of `cls` without a one-line description, as 'Class.field: why'."""
    found = _comments(cls)
    out = []
    for f in dataclasses.fields(cls):
        text, n_lines = found.get(f.name, ("", 0))
        if n_lines == 0:
            out.append(f"{cls.__name__}.{f.name}: no `#` comment line directly above the field")
        elif n_lines > 1:
            out.append(f"{cls.__name__}.{f.name}: {n_lines} comment lines above the field (one line describes it)")
        elif not text:
            out.append(f"{cls.__name__}.{f.name}: empty comment")
    return out


@functools.cache
def _comments(cls: type) -> dict[str, tuple[str, int]]:
    """{field: (the comment line directly above it, how many comment lines the block has)}."""
    lines, _ = inspect.getsourcelines(cls)
    source = textwrap.dedent("".join(lines))
    body = ast.parse(source).body[0]
    assert isinstance(body, ast.ClassDef)
    src_lines = source.splitlines()
    out: dict[str, tuple[str, int]] = {}
    for node in body.body:
        if not (isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name)):
            continue
        above = node.lineno - 2  # 0-based index of the line above the field
        n = 0
        while above - n >= 0 and src_lines[above - n].strip().startswith("#"):
            n += 1
        text = src_lines[above].strip().lstrip("#").strip() if n else ""
        out[node.target.id] = (text, n)
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


def settings(loaded: ConfigSources) -> list[Setting]:
    """Every leaf of the effective configuration, in the order of the classes' fields.

    A section that is null (`rgbd_calibration` unless a preset gives it) is one leaf."""
    return list(_walk(LiteVLocConfig, loaded.config, LiteVLocConfig(), (), loaded))


def all_fields() -> list[Setting]:
    """Every field of every settings class at its place in the tree, with the code default as
    value (a null section's fields with their class defaults; `value` is `REQUIRED` where the
    class has none)."""
    empty = ConfigSources(LiteVLocConfig(), Path("-"), {}, {})
    return list(_walk(LiteVLocConfig, LiteVLocConfig(), LiteVLocConfig(), (), empty, expand_null=True))


class _Required:
    def __repr__(self) -> str:
        return "required"


REQUIRED: Any = _Required()


def _walk(cls: type, value: Any, default: Any, prefix: tuple[str, ...], loaded: ConfigSources,
          expand_null: bool = False) -> Iterator[Setting]:
    hints = typing.get_type_hints(cls)
    notes = field_descriptions(cls)
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
            yield from _walk(section, v, d, parts, loaded, expand_null)
            continue
        if _has(loaded.override_data, parts):
            origin = OVERRIDE
        elif _has(loaded.file_data, parts):
            origin = loaded.path.name
        else:
            origin = DEFAULT
        yield Setting(".".join(parts), str(f.type), v, d, notes.get(f.name, ""), origin)


def format_value(v: Any) -> str:
    """A value as YAML would write it inline (tuples as lists, None as null)."""
    if v is None:
        return "null"
    if v is REQUIRED:
        return "required"
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, tuple | list):
        return "[" + ", ".join(format_value(x) for x in v) + "]"
    if isinstance(v, str):
        return repr(v) if v == "" or v != v.strip() else v
    if isinstance(v, Mapping):
        return "{" + ", ".join(f"{k}: {format_value(x)}" for k, x in v.items()) + "}"
    return str(v)


def render_text(rows: Sequence[Setting]) -> str:
    """`key = value  [origin]  description`, one line per setting, columns aligned."""
    if not rows:
        return ""
    left = [f"{r.key} = {format_value(r.value)}" for r in rows]
    origin = [f"[{r.origin}]" for r in rows]
    w1, w2 = max(map(len, left)), max(map(len, origin))
    return "\n".join(f"{a:<{w1}}  {o:<{w2}}  {r.description}".rstrip()
                     for a, o, r in zip(left, origin, rows, strict=True)) + "\n"


def render_markdown(presets: Mapping[str, ConfigSources]) -> str:
    """docs/parameters.md: every field of every settings class, grouped by section, with its
    type, code default, description and the presets that set it."""
    rows = all_fields()
    by_preset = {name: {r.key: r for r in settings(loaded) if r.origin != DEFAULT} for name, loaded in presets.items()}
    out = ["# Parameters", "",
           "Generated by `python docs/generate.py` from the settings classes (`base/params/*.py`,",
           "`config/schema.py`) and the presets (`config/presets/*.yaml`); do not edit by hand.",
           "Every key can be set in a YAML file or with `--set KEY=VALUE`; `litevloc config show",
           "[--config P] [--set KEY=VALUE]` prints the effective values and where each came from.",
           "How the configuration works: [configuration.md](configuration.md).", ""]
    section = None
    for r in rows:
        top = r.key.split(".")[0] if "." in r.key else "top level"
        if top != section:
            section = top
            out += ["", f"## {top}" if top == "top level" else f"## `{top}`", "",
                    "| key | type | default | description | presets |", "|---|---|---|---|---|"]
        presets_cell = ", ".join(f"{name}: `{format_value(rows_p[r.key].value)}`"
                                 for name, rows_p in by_preset.items() if r.key in rows_p)
        cells = (f"`{r.key}`", f"`{r.type}`", f"`{format_value(r.value)}`", r.description, presets_cell)
        out.append("| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |")
    return "\n".join(out).replace("\n\n\n", "\n\n") + "\n"
