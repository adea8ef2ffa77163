"""Typed configuration: `load_config(preset or path, overrides)` -> `LiteVLocConfig`."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from litevloc.base.loader import ConfigError, apply_override, from_mapping, load_yaml
from litevloc.config.schema import LiteVLocConfig

PRESETS_DIR = Path(__file__).resolve().parent / "presets"

__all__ = ["PRESETS_DIR", "ConfigError", "LiteVLocConfig", "load_config", "preset_names", "resolve_config_path"]


def preset_names() -> list[str]:
    """Names of the shipped presets (file stems in config/presets)."""
    return sorted(p.stem for p in PRESETS_DIR.glob("*.yaml"))


def resolve_config_path(name_or_path: str | Path) -> Path:
    """A preset name (`default`, `7scenes`) or a path to a YAML file -> existing path."""
    p = Path(name_or_path)
    if p.suffix in (".yaml", ".yml"):
        if p.is_file():
            return p
        shipped = PRESETS_DIR / p.name
        if (p.parent == Path(".") or str(p.parent) == "config") and shipped.is_file():
            return shipped
        raise ConfigError(f"config file not found: {p}")
    preset = PRESETS_DIR / f"{name_or_path}.yaml"
    if preset.is_file():
        return preset
    raise ConfigError(f"unknown config {str(name_or_path)!r}: not a file, and presets are {preset_names()}")


def load_config(name_or_path: str | Path | None = None, overrides: Sequence[str] = ()) -> LiteVLocConfig:
    """Load a preset or YAML file and apply `key=value` overrides.

    None means the `default` preset: a command run without `--config` behaves exactly as
    with `--config default` (one set of defaults a user can see; tested).
    """
    path = resolve_config_path("default" if name_or_path is None else name_or_path)
    data = load_yaml(path)
    source = str(path)
    for ov in overrides:
        data = apply_override(data, ov)
    if overrides:
        source += f" (with overrides {list(overrides)})"
    return from_mapping(LiteVLocConfig, data, source)
