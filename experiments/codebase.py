"""How well a newcomer can hold the codebase in their head (`bench/codebase.py`): the figures of
issue 44's before/after table, read statically from a source tree (any commit's, exported with
`git archive`), so the same code measures before and after.

* README size; modules over 500 lines and functions over 100 lines in the library packages;
* settings: fields of the settings classes (dataclasses named `*Params` / `*Config`) and how
  many of them a configuration file reaches (from `LiteVLocConfig` through field annotations);
* shims: modules that only re-export, `import X as X`, and imports of a name through a module
  that does not define it (two import paths for one name);
* duplicate blocks: pairs of six or more similar lines within the library packages (the
  `duplicates` tool);
* tests that localize the frames their map was built from: the test functions that both build a
  map and localize, each judged in `LOCALIZATION_TESTS` (a new one fails the count until judged).
"""

from __future__ import annotations

import ast
import re
import subprocess
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

PACKAGES = ("base", "config", "hw", "sim", "models", "pipelines", "runtime", "cli", "experiments")
SETTINGS_SUFFIXES = ("Params", "Config")
# test id -> whether it localizes frames its own map was built from (judged by reading it)
LOCALIZATION_TESTS: dict[str, bool] = {
    # before (bb82192): 7-Scenes maps of frames 0:120:4 / 0:60:4 / 0:80:4 queried with frames they contain
    "tests/runtime/test_cli_map_localize.py::small_map": True,  # 0:120:4, queried with 30:90:6
    "tests/runtime/test_replay_runtime.py::test_replay_through_runtime_matches_ground_truth": True,
    "tests/runtime/test_vloc_process.py::small_map": True,
    "tests/runtime/test_view.py::test_replay_and_localize_save_the_view": True,
    # held out: the map of the mapping pass (0:500:5), queries from the query pass (500-999)
    "tests/runtime/test_realtime_stack.py::inputs": False,
    "tests/conftest.py::seven_scenes_held_out": False,
    # other frames of the same pass (interleaved, never the map's own)
    "tests/pipelines/topomap/test_update.py::base_map": False,
    # simulator: the mapping pass maps, another route or start localizes
    "tests/runtime/test_sim_navigate.py::small_map": False,
    # build only: no localization in the test itself
    "tests/runtime/test_cli_map_localize.py::test_map_build_info_plot": False,
    "tests/runtime/test_sim_navigate.py::test_map_from_the_simulator_reports_how_its_keyframes_were_chosen": False,
    "tests/runtime/test_sim_navigate.py::test_ensure_map_passes_build_overrides_and_reuses_a_built_map": False,
}


@dataclass
class CodebaseFigures:
    """The before/after figures of one source tree."""

    readme_bytes: int = 0
    modules_over_500: list[str] = field(default_factory=list)
    functions_over_100: list[str] = field(default_factory=list)
    settings_fields: int = 0
    settings_fields_reachable: int = 0
    settings_classes_unreachable: list[str] = field(default_factory=list)
    shim_modules: list[str] = field(default_factory=list)
    import_as_same_name: int = 0
    imports_through_another_module: list[str] = field(default_factory=list)
    duplicate_pairs: int = 0
    duplicate_pairs_not_boilerplate: int = 0  # the tool's rows not marked boilerplate
    tests_localizing_own_frames: list[str] = field(default_factory=list)
    tests_not_judged: list[str] = field(default_factory=list)


def _library_files(root: Path) -> Iterator[Path]:
    for pkg in PACKAGES:
        if (root / pkg).is_dir():
            yield from sorted((root / pkg).rglob("*.py"))


def _module_of(root: Path, path: Path) -> str:
    parts = path.relative_to(root).with_suffix("").parts
    return "litevloc." + ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _sizes(root: Path, fig: CodebaseFigures) -> None:
    for p in _library_files(root):
        text = p.read_text()
        rel = str(p.relative_to(root))
        if text.count("\n") > 500:
            fig.modules_over_500.append(rel)
        for node in ast.walk(ast.parse(text)):
            if (isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef) and node.end_lineno is not None
                    and node.end_lineno - node.lineno + 1 > 100):
                fig.functions_over_100.append(f"{rel}::{node.name}")


def _settings(root: Path, fig: CodebaseFigures) -> None:
    classes: dict[str, tuple[str, list[str]]] = {}  # name -> (file, field annotations)
    for p in _library_files(root):
        for node in ast.walk(ast.parse(p.read_text())):
            if (isinstance(node, ast.ClassDef) and node.name.endswith(SETTINGS_SUFFIXES)
                    and any("dataclass" in ast.unparse(d) for d in node.decorator_list)):
                anns = [ast.unparse(s.annotation) for s in node.body
                        if isinstance(s, ast.AnnAssign) and isinstance(s.target, ast.Name)]
                classes[node.name] = (str(p.relative_to(root)), anns)
    # every dataclass the tree can reach, settings-named or not (LevelThresholds, ColorDepthCalibration)
    all_dataclasses: dict[str, list[str]] = {}
    for p in _library_files(root):
        for node in ast.walk(ast.parse(p.read_text())):
            if isinstance(node, ast.ClassDef) and any("dataclass" in ast.unparse(d) for d in node.decorator_list):
                all_dataclasses.setdefault(node.name, [ast.unparse(s.annotation) for s in node.body
                                                       if isinstance(s, ast.AnnAssign)])
    reached, todo = set(), ["LiteVLocConfig"]
    while todo:
        name = todo.pop()
        if name in reached or name not in all_dataclasses:
            continue
        reached.add(name)
        for ann in all_dataclasses[name]:
            todo += [w for w in re.findall(r"[A-Za-z_]\w*", ann) if w in all_dataclasses]
    fig.settings_fields = sum(len(a) for _, a in classes.values())
    fig.settings_fields_reachable = sum(len(a) for n, (_, a) in classes.items() if n in reached)
    fig.settings_classes_unreachable = sorted(f"{f}::{n}" for n, (f, _) in classes.items() if n not in reached)


def _shims(root: Path, fig: CodebaseFigures) -> None:
    defined: dict[str, set[str]] = {}
    trees = {}
    for p in _library_files(root):
        tree = ast.parse(p.read_text())
        mod = _module_of(root, p)
        trees[mod] = (p, tree)
        names: set[str] = set()
        for node in tree.body:
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
                names.add(node.name)
            elif isinstance(node, ast.Assign):
                names.update(t.id for t in node.targets if isinstance(t, ast.Name))
            elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
                names.add(node.target.id)
            elif isinstance(node, ast.If | ast.Try):  # names defined under a guard
                for sub in ast.walk(node):
                    if isinstance(sub, ast.FunctionDef | ast.ClassDef):
                        names.add(sub.name)
        defined[mod] = names
    for p, tree in trees.values():
        rel = str(p.relative_to(root))
        body = [n for n in tree.body if not (isinstance(n, ast.Expr) and isinstance(n.value, ast.Constant))]
        imports = [n for n in body if isinstance(n, ast.Import | ast.ImportFrom)]
        if imports and all(isinstance(n, ast.Import | ast.ImportFrom)
                           or (isinstance(n, ast.Assign) and any(getattr(t, "id", "") == "__all__" for t in n.targets))
                           for n in body) and not rel.endswith("__init__.py"):
            fig.shim_modules.append(rel)
        for imp in ast.walk(tree):
            if isinstance(imp, ast.Import | ast.ImportFrom):
                fig.import_as_same_name += sum(1 for a in imp.names if a.asname and a.asname == a.name.split(".")[-1])
            if isinstance(imp, ast.ImportFrom) and imp.module in defined and imp.level == 0:
                for a in imp.names:
                    if a.name != "*" and a.name not in defined[imp.module] and f"{imp.module}.{a.name}" not in defined:
                        fig.imports_through_another_module.append(f"{rel}: {imp.module}.{a.name}")


def _duplicates(root: Path, fig: CodebaseFigures) -> None:
    r = subprocess.run(["duplicates", "--repo", str(root), "--most", "200", "--seconds", "120"], capture_output=True,
                       text=True, timeout=300)
    lib = tuple(f"{p}/" for p in PACKAGES)
    for line in r.stdout.splitlines():
        m = re.match(r"D\d+ (\S+?):\d+-\d+ ~ (\S+?):\d+-\d+", line)
        if m and m.group(1).startswith(lib) and m.group(2).startswith(lib):
            fig.duplicate_pairs += 1
            fig.duplicate_pairs_not_boilerplate += "boilerplate" not in line


def _localization_tests(root: Path, fig: CodebaseFigures) -> None:
    """Test functions and fixtures that build a map and localize or replay against it."""
    build = re.compile(r"\"map\", \"build\"|MapBuilder\(|build_7scenes\(|ensure_map\(|HELD_OUT_MAP_ARGS")
    localize = re.compile(r"\"localize\"|\"replay\"|localize_global\(|localize_local\(|VlocProcess\(|run_navigation\(")
    for p in sorted((root / "tests").rglob("*.py")):
        text = p.read_text()
        rel = str(p.relative_to(root))
        if not (build.search(text) and localize.search(text)):
            continue
        for node in ast.parse(text).body:
            if isinstance(node, ast.FunctionDef) and build.search(ast.get_source_segment(text, node) or ""):
                key = f"{rel}::{node.name}"
                if key in LOCALIZATION_TESTS:
                    if LOCALIZATION_TESTS[key]:
                        fig.tests_localizing_own_frames.append(key)
                else:
                    fig.tests_not_judged.append(key)


def measure(root: Path) -> CodebaseFigures:
    fig = CodebaseFigures()
    fig.readme_bytes = (root / "README.md").stat().st_size
    _sizes(root, fig)
    _settings(root, fig)
    _shims(root, fig)
    _duplicates(root, fig)
    _localization_tests(root, fig)
    return fig
