"""How well a newcomer can hold the codebase in their head (`bench/codebase.py`): the figures of
a before/after comparison, read statically from a source tree (any commit's, exported with
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

Issue 79's figures, in the library (`LIBRARY`: base config hw models pipelines runtime sim cli):

* size limits: modules over 500 lines, classes over 300, functions over 80 (a function's or
  class's lines run from its `def`/`class` line to its last line; nested ones count on their own);
* settings as a configuration file sees them, walked from `LiteVLocConfig` through the field
  annotations: a field whose annotation names a dataclass is a *section*, every other field a
  *field* (counted once per path: a class reached twice counts twice); the nesting depth is the
  most sections on a path to a field (`localization.refine.x`: 2); the largest section by its own
  fields. Descriptions are judged once per declaration (`Class.field`): the `#` line directly
  above the field, or a `description=` / `doc=` / `help=` string of the call that declares its
  default; one does not stand alone when it starts with "..." or with a word that continues
  another sentence (`CONTINUATION`: "and", "then", "that", ...);
* modules per folder: `.py` files other than `__init__.py` directly in each library folder;
* the files a newcomer opens for each of issue 79's three changes (`CHANGES`), by this rule: the
  distinct library files that define one of the change's entry points (the code that must be
  edited), plus the files the change creates (`new_files`), plus, for a change that adds
  a value to a selector setting (`selector`: a field whose annotation is a `Literal`), the file
  declaring that `Literal` and every file holding a dispatch over its values: an `if`/`elif`/
  `match` that compares an expression ending in the selector's name (`kind`, `cfg.source.kind`)
  with one of the values, or a dict literal keyed by two or more of them. A change lists its
  entry points per layout of the tree, newest first; the first layout whose entry points all
  resolve (the module exists and defines a name matching each `fnmatch` pattern) is measured,
  and a change none resolves is reported unresolved (count None).
"""

from __future__ import annotations

import ast
import fnmatch
import re
import subprocess
from collections import Counter
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

PACKAGES = ("base", "config", "hw", "sim", "models", "pipelines", "runtime", "cli", "experiments")
LIBRARY = ("base", "config", "hw", "models", "pipelines", "runtime", "sim", "cli")  # issue 79's size limits
MODULE_LINES, CLASS_LINES, FUNCTION_LINES, FOLDER_MODULES = 500, 300, 80, 12
# first words of a setting description that continues another one instead of standing alone
CONTINUATION = ("and", "or", "but", "nor", "then", "that", "those", "these", "same", "likewise", "otherwise", "else",
                "ditto")


@dataclass(frozen=True)
class Layout:
    """One layout of a tree for one change: entry points `module:qualname` (qualname an
    `fnmatch` pattern; none = the whole module), files the change creates, and the selector
    setting (`module:Class.field`) it adds a value to."""

    label: str
    entries: tuple[str, ...]
    new_files: int = 0
    selector: str | None = None


_PUBLISH_BEFORE = ("litevloc.pipelines.fusion.online:OnlineFusion._output",)
# issue 79's three changes; the layouts newest first
CHANGES: dict[str, tuple[Layout, ...]] = {
    "Change how GL verifies a candidate": (
        # a check's module and GL's ordered list of checks
        Layout("after #79", ("litevloc.pipelines.localization.checks.support",
                             "litevloc.pipelines.localization.global_search:GlobalSearch._search")),
        Layout("7bea613", ("litevloc.pipelines.localization.vloc:VisualLocalizer._verify*",
                           "litevloc.pipelines.localization.vloc:VisualLocalizer._ambiguity",
                           "litevloc.pipelines.localization.query", "litevloc.pipelines.localization.passes",
                           "litevloc.pipelines.localization.refine", "litevloc.pipelines.localization.distinct",
                           "litevloc.pipelines.localization.second_look",
                           "litevloc.pipelines.localization.see_through",
                           "litevloc.pipelines.localization.depth_align")),
        # before issue 44's split: the checks were methods of VisualLocalizer (read from that tree)
        Layout("bb82192", ("litevloc.pipelines.localization.vloc:VisualLocalizer._verify*",
                           "litevloc.pipelines.localization.vloc:VisualLocalizer._flat_support",
                           "litevloc.pipelines.localization.vloc:VisualLocalizer._joint",
                           "litevloc.pipelines.localization.refine")),
    ),
    "Add a camera driver": (
        # the new `StreamSource` module and its entry in the registry of source kinds
        Layout("after #79", ("litevloc.runtime.sources",), new_files=1),
        # the new `StreamSource` module; its kind in the settings and each dispatch over the kinds
        Layout("7bea613", (), new_files=1, selector="litevloc.config.schema:SourceConfig.kind"),
    ),
    "Change how the fused pose is published": (
        Layout("after #79", ("litevloc.runtime.service.core:LocalizationCore._publish_decision",
                             "litevloc.runtime.transport.bus:LiteVLocPublisher.publish_pose")),
        Layout("728ecba", (*_PUBLISH_BEFORE, "litevloc.runtime.service.core:LocalizationCore.odometry",
                           "litevloc.runtime.service.shell:Service._handle_publish",
                           "litevloc.runtime.transport.bus:LiteVLocPublisher.publish_pose")),
        Layout("7bea613", (*_PUBLISH_BEFORE, "litevloc.runtime.localization_core:LocalizationCore.odometry",
                           "litevloc.runtime.service:Service._handle_publish",
                           "litevloc.runtime.bus:LiteVLocPublisher.publish_pose")),
    ),
}
SETTINGS_SUFFIXES = ("Params", "Config")
# test id -> whether it localizes frames its own map was built from (judged by reading it)
LOCALIZATION_TESTS: dict[str, bool] = {
    # these tests localize 7-Scenes frames their own map was built from (True)
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
    # issue 79 (see the module docstring)
    library_modules_over_500: list[str] = field(default_factory=list)  # "path (lines)"
    library_classes_over_300: list[str] = field(default_factory=list)  # "path::Class (lines)"
    library_functions_over_80: list[str] = field(default_factory=list)  # "path::Class.function (lines)"
    settings_leaf_fields: int = 0
    settings_sections: int = 0
    settings_max_depth: int = 0
    settings_largest_section: str = ""
    settings_largest_section_fields: int = 0
    settings_not_standalone: list[str] = field(default_factory=list)  # "Class.field", once per declaration
    settings_undescribed: list[str] = field(default_factory=list)  # "Class.field"
    modules_per_folder_max: int = 0
    modules_per_folder_max_folder: str = ""
    folders_over_12: list[str] = field(default_factory=list)  # "folder (modules)"
    change_files: dict[str, int | None] = field(default_factory=dict)  # change -> files a newcomer opens
    change_layout: dict[str, str] = field(default_factory=dict)
    change_opened: dict[str, list[str]] = field(default_factory=dict)  # change -> the files counted
    change_unresolved: dict[str, list[str]] = field(default_factory=dict)  # entry points no layout resolves


def _assigned(targets: Sequence[ast.expr]) -> Iterator[str]:
    """The names an assignment binds (`A, B = 0, 1` binds both)."""
    for t in targets:
        yield from (e.id for e in [t, *getattr(t, "elts", [])] if isinstance(e, ast.Name))


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
                names.update(_assigned(node.targets))
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


def _library(root: Path) -> Iterator[Path]:
    for pkg in LIBRARY:
        if (root / pkg).is_dir():
            yield from sorted((root / pkg).rglob("*.py"))


def _defs(node: ast.AST, prefix: str = "") -> Iterator[tuple[str, ast.AST]]:
    """(qualname, node) of every function and class under `node`, nested ones included."""
    for child in ast.iter_child_nodes(node):
        if isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
            yield f"{prefix}{child.name}", child
            yield from _defs(child, f"{prefix}{child.name}.")
        else:
            yield from _defs(child, prefix)


def _limits(root: Path, fig: CodebaseFigures) -> None:
    for p in _library(root):
        text = p.read_text()
        rel = str(p.relative_to(root))
        if (n := text.count("\n")) > MODULE_LINES:
            fig.library_modules_over_500.append(f"{rel} ({n})")
        for qual, node in _defs(ast.parse(text)):
            lines = getattr(node, "end_lineno", 0) - getattr(node, "lineno", 0) + 1
            over = fig.library_classes_over_300 if isinstance(node, ast.ClassDef) else fig.library_functions_over_80
            if lines > (CLASS_LINES if isinstance(node, ast.ClassDef) else FUNCTION_LINES):
                over.append(f"{rel}::{qual} ({lines})")


def _description(st: ast.AnnAssign, lines: list[str]) -> str | None:
    """A field's description: the `#` line directly above it, or a description keyword of the
    call that declares its default; None when it has none."""
    above = lines[st.lineno - 2].strip() if st.lineno >= 2 else ""
    if above.startswith("#"):
        return above.lstrip("#").strip()
    if isinstance(st.value, ast.Call):
        for kw in st.value.keywords:
            if kw.arg in ("description", "doc", "help") and isinstance(kw.value, ast.Constant):
                return str(kw.value.value)
    return None


def _stands_alone(desc: str) -> bool:
    first = re.match(r"[A-Za-z]+", desc)
    return not desc.startswith(("...", "\u2026")) and not (first and first.group(0) in CONTINUATION)


def _settings_tree(root: Path, fig: CodebaseFigures) -> None:
    """Sections, fields, depth and descriptions from `LiteVLocConfig` (see the module docstring)."""
    classes: dict[str, tuple[ast.ClassDef, list[str]]] = {}
    for p in _library(root):
        text = p.read_text()
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, ast.ClassDef) and any("dataclass" in ast.unparse(d) for d in node.decorator_list):
                classes.setdefault(node.name, (node, text.splitlines()))
    largest, described = ("", -1), set()
    todo = [("LiteVLocConfig", "", 0)] if "LiteVLocConfig" in classes else []
    while todo:
        name, path, depth = todo.pop()
        node, lines = classes[name]
        own = 0
        for st in node.body:
            if not isinstance(st, ast.AnnAssign) or not isinstance(st.target, ast.Name):
                continue
            ann = ast.unparse(st.annotation)
            dotted = f"{path}.{st.target.id}" if path else st.target.id
            subs = [w for w in re.findall(r"[A-Za-z_]\w*", ann) if w in classes]
            if ann.startswith(("ClassVar", "typing.ClassVar")):
                continue
            if subs and depth < 12:  # (a bound against a class that contains itself)
                fig.settings_sections += len(subs)
                todo += [(w, dotted, depth + 1) for w in subs]
                continue
            own += 1
            fig.settings_leaf_fields += 1
            fig.settings_max_depth = max(fig.settings_max_depth, depth)
            if (decl := f"{name}.{st.target.id}") in described:
                continue
            described.add(decl)
            desc = _description(st, lines)
            if desc is None:
                fig.settings_undescribed.append(decl)
            elif not _stands_alone(desc):
                fig.settings_not_standalone.append(decl)
        if own > largest[1]:
            largest = (path or "(top level)", own)
    fig.settings_largest_section, fig.settings_largest_section_fields = largest[0], max(largest[1], 0)
    fig.settings_not_standalone.sort()
    fig.settings_undescribed.sort()


def _folders(root: Path, fig: CodebaseFigures) -> None:
    counts = Counter(str(p.parent.relative_to(root)) for p in _library(root) if p.name != "__init__.py")
    if counts:
        fig.modules_per_folder_max_folder, fig.modules_per_folder_max = max(counts.items(), key=lambda kv: kv[1])
    fig.folders_over_12 = [f"{d} ({n})" for d, n in sorted(counts.items()) if n > FOLDER_MODULES]


def _module_file(root: Path, module: str) -> Path | None:
    parts = module.split(".")[1:]  # without "litevloc."
    for cand in (Path(*parts).with_suffix(".py"), Path(*parts, "__init__.py")):
        if (root / cand).is_file():
            return cand
    return None


def _names(tree: ast.Module) -> set[str]:
    """Qualnames a module defines: functions, classes, methods, module and class attributes."""
    names = set()
    for qual, node in [("", tree), *_defs(tree)]:
        names.add(qual)
        for st in getattr(node, "body", []):
            targets = [st.target] if isinstance(st, ast.AnnAssign) else st.targets if isinstance(st, ast.Assign) else []
            names.update(f"{qual}.{n}" if qual else n for n in _assigned(targets))
    return names


def _resolve(root: Path, entry: str) -> Path | None:
    """The file defining entry point `module:qualname` (a pattern), None when none does."""
    module, _, qual = entry.partition(":")
    path = _module_file(root, module)
    if path is None or (qual and not fnmatch.filter(_names(ast.parse((root / path).read_text())), qual)):
        return None
    return path


def _literal_values(root: Path, selector: str) -> tuple[Path | None, set[str]]:
    """The file and the values of a selector field `module:Class.field` annotated `Literal[...]`."""
    path = _resolve(root, selector)
    cls, _, name = selector.partition(":")[2].rpartition(".")
    if path is None:
        return None, set()
    for qual, node in _defs(ast.parse((root / path).read_text())):
        for st in getattr(node, "body", []) if qual == cls else []:
            if (isinstance(st, ast.AnnAssign) and isinstance(st.target, ast.Name) and st.target.id == name
                    and ast.unparse(st.annotation).startswith(("Literal[", "typing.Literal["))):
                return path, {c.value for c in ast.walk(st.annotation) if isinstance(c, ast.Constant)
                               and isinstance(c.value, str)}
    return None, set()


def _ends_in(e: ast.expr, attr: str) -> bool:
    return (isinstance(e, ast.Name) and e.id == attr) or (isinstance(e, ast.Attribute) and e.attr == attr)


def _dispatches(tree: ast.Module, attr: str, values: set[str]) -> bool:
    """Whether a module compares an expression ending in `attr` with one of `values` (in a
    condition or a `match`), or keys a dict literal by two or more of them."""
    def consts(e: ast.AST) -> set[object]:
        return {c.value for c in [e, *getattr(e, "elts", [])] if isinstance(c, ast.Constant)}

    for n in ast.walk(tree):
        if isinstance(n, ast.Compare) and _ends_in(n.left, attr) and any(consts(c) & values for c in n.comparators):
            return True
        cases = [v for c in n.cases for v in ast.walk(c.pattern)] if isinstance(n, ast.Match) else []
        if isinstance(n, ast.Match) and _ends_in(n.subject, attr) and any(
                isinstance(v, ast.MatchValue) and consts(v.value) & values for v in cases):
            return True
        if isinstance(n, ast.Dict) and len({k for key in n.keys if key is not None for k in consts(key)} & values) >= 2:
            return True
    return False


def _changes(root: Path, fig: CodebaseFigures) -> None:
    """The files a newcomer opens for each of `CHANGES` (the rule: the module docstring)."""
    for change, layouts in CHANGES.items():
        unresolved: list[str] = []
        for layout in layouts:
            files = {e: _resolve(root, e) for e in (*layout.entries, *([layout.selector] if layout.selector else []))}
            if any(f is None for f in files.values()):
                unresolved += [f"{layout.label}: {e}" for e, f in files.items() if f is None]
                continue
            opened = {str(f) for e, f in files.items() if e != layout.selector}
            if layout.selector:
                lit, values = _literal_values(root, layout.selector)
                attr = layout.selector.rpartition(".")[2]
                opened |= {str(lit)} if lit else set()
                opened |= {str(p.relative_to(root)) for p in _library(root) if values
                           and _dispatches(ast.parse(p.read_text()), attr, values)}
            fig.change_files[change] = len(opened) + layout.new_files
            fig.change_layout[change] = layout.label
            fig.change_opened[change] = sorted(opened) + [f"(new file {k + 1})" for k in range(layout.new_files)]
            break
        else:
            fig.change_files[change] = None
            fig.change_unresolved[change] = unresolved


def measure(root: Path, duplicates: bool = True) -> CodebaseFigures:
    """All figures of the source tree at `root`; `duplicates` False skips the (slow)
    duplicate-block search."""
    fig = CodebaseFigures()
    fig.readme_bytes = (root / "README.md").stat().st_size if (root / "README.md").is_file() else 0
    _sizes(root, fig)
    _settings(root, fig)
    _shims(root, fig)
    if duplicates:
        _duplicates(root, fig)
    _localization_tests(root, fig)
    _limits(root, fig)
    _settings_tree(root, fig)
    _folders(root, fig)
    _changes(root, fig)
    return fig
