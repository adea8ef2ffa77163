"""One error hierarchy: every domain error class in the packages derives from LiteVLocError.

The classes are found by reading the sources (so a new `class XError(ValueError)` that
forgets the base fails here), then imported and checked; each keeps the built-in base
that callers catch today (ConfigError is still a ValueError, StreamError a RuntimeError).
"""

from __future__ import annotations

import ast
import importlib
from pathlib import Path

import pytest

from litevloc.base.errors import LiteVLocError

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("base", "config", "hw", "sim", "models", "pipelines", "runtime", "cli")
# Exceptions that are control flow, not errors: a closed/empty queue ends a consumer's loop.
NOT_ERRORS = {"QueueClosed", "QueueEmpty"}
BUILTIN_BASES = {"Exception", "ValueError", "RuntimeError", "OSError", "KeyError", "TypeError", "LookupError"}


def _exception_classes() -> list[tuple[str, str, str | None]]:
    """(module, class name, its built-in base or None) of every class in the packages whose
    name ends in Error/Overflow or that derives from a built-in exception (by source)."""
    found = []
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            if "export" in path.parts:  # models/export imports torch
                continue
            tree = ast.parse(path.read_text())
            for node in tree.body:
                if not isinstance(node, ast.ClassDef) or node.name in NOT_ERRORS:
                    continue
                bases = [b.id for b in node.bases if isinstance(b, ast.Name)]
                builtin = next((b for b in bases if b in BUILTIN_BASES), None)
                if builtin or (node.name.endswith(("Error", "Overflow")) and bases):
                    mod = "litevloc." + ".".join(path.relative_to(ROOT).with_suffix("").parts)
                    found.append((mod, node.name, builtin))
    return found


CLASSES = _exception_classes()


def test_the_scan_finds_the_known_errors() -> None:
    names = {name for _, name, _ in CLASSES}
    assert {"ConfigError", "StreamError", "MapFormatError", "ModelError", "RenderError", "NavigationError",
            "NavigationRunError", "ServiceError", "BusError", "GeometryError", "UserError"} <= names


@pytest.mark.parametrize(("module", "name", "builtin"), CLASSES, ids=[c[1] for c in CLASSES])
def test_every_domain_error_derives_from_the_base(module: str, name: str, builtin: str | None) -> None:
    cls = getattr(importlib.import_module(module), name)
    assert issubclass(cls, LiteVLocError), f"{module}.{name} does not derive from LiteVLocError"
    if builtin and builtin != "Exception":
        import builtins

        assert issubclass(cls, getattr(builtins, builtin)), f"{name} lost its {builtin} base"


def test_builtin_bases_kept_for_callers() -> None:
    from litevloc.base.loader import ConfigError
    from litevloc.hw.messages import StreamError
    from litevloc.pipelines.topomap.io import MapFormatError

    with pytest.raises(ValueError):
        raise ConfigError("x")
    with pytest.raises(RuntimeError):
        raise StreamError("x")
    with pytest.raises(ValueError):
        raise MapFormatError("x")
