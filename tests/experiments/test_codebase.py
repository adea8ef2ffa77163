"""`measure` on a tiny synthetic tree whose figures are known by construction: the size limits,
the settings tree and its descriptions, modules per folder, and the files of a change by the
stated rule (entry points per layout, a selector's Literal and the dispatches over it)."""

from __future__ import annotations

from pathlib import Path

import pytest

from litevloc.experiments import codebase
from litevloc.experiments.codebase import Layout, measure

SCHEMA = '''
from dataclasses import dataclass, field
from typing import ClassVar, Literal


@dataclass(frozen=True)
class SourceConfig:
    # what the data come from
    kind: Literal["file", "cam"] = "file"


@dataclass(frozen=True)
class InnerParams:
    # the smallest step (m)
    step_m: float = 0.1
    # ... and the largest (m)
    max_m: float = 1.0


@dataclass(frozen=True)
class LocParams:
    # how many candidates are verified
    candidates: int = 3
    # then the longest wait (s)
    wait_s: float = 1.0
    radius_m: float = 2.0
    # steps of the search
    inner: InnerParams = field(default_factory=InnerParams)
    LIMIT: ClassVar[int] = 3


@dataclass(frozen=True)
class LiteVLocConfig:
    # where the data come from
    source: SourceConfig = field(default_factory=SourceConfig)
    # localization
    loc: LocParams = field(default_factory=LocParams)
    # random seed
    seed: int = 0
'''

DISPATCH = '''
def open_source(cfg):
    if cfg.source.kind == "cam":
        return 1
    return 0
'''
TABLE = 'OPENERS = {"file": 1, "cam": 2}\n'
NOT_A_DISPATCH = 'def walls(faces):\n    return [f for f in faces if f.kind == "wall"]\n'
VERIFY = '''
class Verifier:
    def verify_pnp(self):
        return 1

    def verify_support(self):
        return 2
'''


def _body(name: str, lines: int) -> str:
    """A function `name` of exactly `lines` lines."""
    return f"def {name}():\n" + "    x = 0\n" * (lines - 2) + "    return x\n"


@pytest.fixture
def tree(tmp_path: Path) -> Path:
    def write(rel: str, text: str) -> None:
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_text(text)

    write("README.md", "# tiny\n")
    write("tests/__init__.py", "")
    write("config/__init__.py", "")
    write("config/schema.py", SCHEMA)
    write("hw/__init__.py", "")
    write("hw/open.py", DISPATCH)
    write("hw/table.py", TABLE)
    write("sim/walls.py", NOT_A_DISPATCH)
    write("pipelines/__init__.py", "")
    write("pipelines/verify.py", VERIFY)
    write("pipelines/long.py", _body("long_enough", 80) + "\n\n" + _body("too_long", 81))
    cls = "class Big:\n" + "    x = 0\n" * 299
    write("pipelines/big_class.py", cls)  # 300 lines: at the limit
    write("pipelines/bigger_class.py", cls + "    y = 1\n")  # 301
    write("pipelines/module.py", "x = 1\n" * 501)
    for k in range(8):  # 13 modules in pipelines/ (with the five above), __init__ not counted
        write(f"pipelines/m{k}.py", "")
    write("experiments/huge.py", "x = 1\n" * 900)  # not in the library
    return tmp_path


@pytest.fixture
def changes(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(codebase, "CHANGES", {
        "verify": (Layout("after", ("litevloc.pipelines.checks:Check",)),  # no such module: the next layout
                   Layout("before", ("litevloc.pipelines.verify:Verifier.verify_*", "litevloc.pipelines.m0"))),
        "driver": (Layout("before", (), new_files=1, selector="litevloc.config.schema:SourceConfig.kind"),),
        "gone": (Layout("before", ("litevloc.pipelines.verify:Verifier.publish",)),),
    })


def test_measure_counts_a_synthetic_tree(tree: Path, changes: None) -> None:
    fig = measure(tree, duplicates=False)
    assert fig.library_modules_over_500 == ["pipelines/module.py (501)"]
    assert fig.library_classes_over_300 == ["pipelines/bigger_class.py::Big (301)"]
    assert fig.library_functions_over_80 == ["pipelines/long.py::too_long (81)"]
    # source.kind, loc.candidates, loc.wait_s, loc.radius_m, loc.inner.step_m, loc.inner.max_m, seed
    assert (fig.settings_leaf_fields, fig.settings_sections, fig.settings_max_depth) == (7, 3, 2)
    assert (fig.settings_largest_section, fig.settings_largest_section_fields) == ("loc", 3)
    assert fig.settings_not_standalone == ["InnerParams.max_m", "LocParams.wait_s"]
    assert fig.settings_undescribed == ["LocParams.radius_m"]
    assert (fig.modules_per_folder_max, fig.modules_per_folder_max_folder) == (13, "pipelines")
    assert fig.folders_over_12 == ["pipelines (13)"]
    assert fig.change_files == {"verify": 2, "driver": 4, "gone": None}
    assert fig.change_layout == {"verify": "before", "driver": "before"}
    assert fig.change_opened["verify"] == ["pipelines/m0.py", "pipelines/verify.py"]
    assert fig.change_opened["driver"] == ["config/schema.py", "hw/open.py", "hw/table.py", "(new file 1)"]
    assert fig.change_unresolved == {"gone": ["before: litevloc.pipelines.verify:Verifier.publish"]}


def test_the_real_table_resolves_in_this_tree() -> None:
    """Every change of `CHANGES` is measured in the working tree (a move that breaks an entry
    point needs a new layout, not a silent None)."""
    fig = codebase.CodebaseFigures()
    codebase._changes(Path(__file__).resolve().parents[2], fig)
    assert set(fig.change_files) == set(codebase.CHANGES)
    assert all(n is not None for n in fig.change_files.values()), fig.change_unresolved
