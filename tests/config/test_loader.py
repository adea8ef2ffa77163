from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import pytest

from litevloc.base.loader import ConfigError, apply_override, from_mapping
from litevloc.config import load_config, preset_names
from litevloc.config.schema import LiteVLocConfig


@dataclass(frozen=True)
class Inner:
    a: int = 1
    b: float = 2.0
    mode: Literal["x", "y"] = "x"
    sizes: tuple[int, ...] = (1, 2)


@dataclass(frozen=True)
class Outer:
    name: str = "n"
    inner: Inner = field(default_factory=Inner)
    maybe: float | None = None


def test_defaults_and_nested_override() -> None:
    cfg = from_mapping(Outer, {"inner": {"a": 5, "b": 3, "sizes": [4]}})
    assert cfg.inner.a == 5 and cfg.inner.b == 3.0 and isinstance(cfg.inner.b, float)
    assert cfg.inner.sizes == (4,) and cfg.name == "n" and cfg.maybe is None


def test_unknown_key_names_key_and_file() -> None:
    with pytest.raises(ConfigError, match=r"unknown key 'inner\.c' in my\.yaml"):
        from_mapping(Outer, {"inner": {"c": 1}}, "my.yaml")


@pytest.mark.parametrize(
    ("data", "pattern"),
    [
        ({"inner": {"a": "five"}}, r"'inner\.a'.*integer"),
        ({"inner": {"a": True}}, r"'inner\.a'.*integer"),
        ({"inner": {"b": "x"}}, r"'inner\.b'.*number"),
        ({"inner": {"mode": "z"}}, r"'inner\.mode'.*one of"),
        ({"inner": {"sizes": 3}}, r"'inner\.sizes'.*list"),
        ({"inner": 3}, r"'inner'.*mapping"),
        ({"name": 1}, r"'name'.*string"),
    ],
)
def test_wrong_types_are_named(data: dict, pattern: str) -> None:
    with pytest.raises(ConfigError, match=pattern):
        from_mapping(Outer, data, "f.yaml")


def test_post_init_validation_is_reported() -> None:
    with pytest.raises(ConfigError, match="rate"):
        from_mapping(LiteVLocConfig, {"replay": {"rate": -1}}, "x.yaml")


def test_presets_load() -> None:
    names = preset_names()
    assert {"default", "7scenes"} <= set(names)
    for n in names:
        assert isinstance(load_config(n), LiteVLocConfig)


def test_override_and_file_errors(tmp_path: Path) -> None:
    cfg = load_config("default", ["replay.rate=2.5", "odometry_sim.drift.sigma_trans_per_m=0.1"])
    assert cfg.replay.rate == 2.5 and cfg.odometry_sim.drift.sigma_trans_per_m == 0.1
    with pytest.raises(ConfigError, match=r"unknown key 'replay\.speed'"):
        load_config("default", ["replay.speed=2"])
    with pytest.raises(ConfigError, match=r"section\.key=value"):
        apply_override({}, "novalue")
    bad = tmp_path / "bad.yaml"
    bad.write_text("replay: [1, 2\n")
    with pytest.raises(ConfigError, match=r"invalid YAML in .*bad\.yaml"):
        load_config(bad)
    notmap = tmp_path / "list.yaml"
    notmap.write_text("- 1\n- 2\n")
    with pytest.raises(ConfigError, match="must be a mapping"):
        load_config(notmap)
    with pytest.raises(ConfigError, match="not found"):
        load_config(tmp_path / "missing.yaml")
    with pytest.raises(ConfigError, match="unknown config"):
        load_config("no-such-preset")


def test_yaml_tags_are_not_executed(tmp_path: Path) -> None:
    evil = tmp_path / "evil.yaml"
    evil.write_text("name: !!python/object/apply:os.system ['echo pwned']\n")
    with pytest.raises(ConfigError, match="invalid YAML"):
        load_config(evil)


def test_no_config_is_the_default_preset() -> None:
    """One set of defaults: a command without --config gets exactly the `default` preset."""
    from litevloc.config import load_config

    assert load_config(None) == load_config("default")
    assert load_config(None, ["mapping.keyframes.budget=7"]) == load_config("default", ["mapping.keyframes.budget=7"])


def test_partial_section_override_keeps_the_section_defaults() -> None:
    """Overriding one key of a nested section keeps that section's default values for the others,
    including a default instance that differs from its class's defaults (covisibility PnP) and
    sections whose class has required keys (diagnostics level thresholds)."""
    from litevloc.config import load_config

    base = load_config(None)
    cfg = load_config(None, ["mapping.covisibility.pnp.reprojection_px=2.5", "diagnostics.vpr_ms.error=2500"])
    assert cfg.mapping.covisibility.pnp.reprojection_px == 2.5
    assert cfg.mapping.covisibility.pnp.min_inliers == base.mapping.covisibility.pnp.min_inliers != 40
    assert cfg.diagnostics.vpr_ms.error == 2500 and cfg.diagnostics.vpr_ms.warn == base.diagnostics.vpr_ms.warn
