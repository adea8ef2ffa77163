"""Issue 44's and issue 79's before/after tables (`litevloc.experiments.codebase`, whose docstring
states how each figure is counted), for the working tree and for any commits given (exported
with `git archive` to a temporary folder). Issue 44: README size, modules over 500 lines,
functions over 100 lines, settings reachable from a configuration file, shims, duplicate
blocks, tests that localize their own mapping frames. Issue 79: the library's size limits,
the settings' fields and nesting, modules per folder, and the files a newcomer opens for each
of its three changes. bb82192 is the tree before issue 44, 7bea613 the tree before issue 79.

    python bench/codebase.py [--before bb82192 7bea613] [--no-duplicates] [--json out/bench/codebase.json]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path

from litevloc.experiments.codebase import CHANGES, FOLDER_MODULES, CodebaseFigures, measure

ROOT = Path(__file__).resolve().parents[1]


def _export(commit: str, dst: Path) -> Path:
    data = subprocess.run(["git", "-C", str(ROOT), "archive", commit], capture_output=True, check=True).stdout
    tar = dst / "tree.tar"
    tar.write_bytes(data)
    with tarfile.open(tar) as t:
        t.extractall(dst / commit, filter="data")
    return dst / commit


def _row(name: str, fig: CodebaseFigures) -> list[str]:
    return [name, f"{fig.readme_bytes / 1024:.1f} KB", str(len(fig.modules_over_500)), str(len(fig.functions_over_100)),
            f"{fig.settings_fields_reachable}/{fig.settings_fields}",
            f"{len(fig.shim_modules)} / {fig.import_as_same_name} / {len(fig.imports_through_another_module)}",
            f"{fig.duplicate_pairs} ({fig.duplicate_pairs_not_boilerplate})", str(len(fig.tests_localizing_own_frames))]


def _row79(name: str, fig: CodebaseFigures) -> list[str]:
    changes = [str(fig.change_files.get(c)) for c in CHANGES]
    return [name, str(len(fig.library_modules_over_500)), str(len(fig.library_classes_over_300)),
            str(len(fig.library_functions_over_80)),
            f"{fig.settings_leaf_fields} / {fig.settings_sections} / {fig.settings_max_depth}",
            f"{fig.settings_largest_section} ({fig.settings_largest_section_fields})",
            str(len(fig.settings_not_standalone)),
            f"{fig.modules_per_folder_max} ({fig.modules_per_folder_max_folder}) / {len(fig.folders_over_12)}",
            *changes]


def _table(header: list[str], rows: list[list[str]]) -> None:
    print("| " + " | ".join(header) + " |\n|" + "---|" * len(header))
    for row in rows:
        print("| " + " | ".join(row) + " |")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--before", nargs="*", default=["bb82192", "7bea613"],
                    help="commits to measure beside the working tree")
    ap.add_argument("--no-duplicates", action="store_true", help="skip the duplicate-block search (minutes a tree)")
    ap.add_argument("--json", type=Path, default=ROOT / "out" / "bench" / "codebase.json")
    args = ap.parse_args()
    figs: dict[str, CodebaseFigures] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for commit in args.before:
            figs[commit] = measure(_export(commit, Path(tmp)), duplicates=not args.no_duplicates)
    figs["working tree"] = measure(ROOT, duplicates=not args.no_duplicates)
    header = ["tree", "README", "modules > 500 lines", "functions > 100 lines", "settings reachable",
              "shim modules / `import X as X` / imports through another module",
              "duplicate pairs in the library (not boilerplate)", "tests localizing their own mapping frames"]
    _table(header, [_row(name, fig) for name, fig in figs.items()])
    for name, fig in figs.items():
        through = fig.imports_through_another_module
        print(f"\n{name}: modules over 500 lines {fig.modules_over_500}; functions over 100 lines "
              f"{fig.functions_over_100}; unreachable settings classes {fig.settings_classes_unreachable}; "
              f"shim modules {fig.shim_modules}; imports through another module {through[:12]}"
              f"{' ...' if len(through) > 12 else ''}; tests localizing their own frames "
              f"{fig.tests_localizing_own_frames}")
        if fig.tests_not_judged:
            print(f"  NOT JUDGED (add them to LOCALIZATION_TESTS): {fig.tests_not_judged}")
    print("\nIssue 79: the library (base config hw models pipelines runtime sim cli); files a newcomer opens per "
          "change (rule: `litevloc.experiments.codebase`)\n")
    _table(["tree", "modules > 500 lines", "classes > 300 lines", "functions > 80 lines",
            "settings fields / sections / max depth", "largest section (fields)", "descriptions not standing alone",
            f"most modules in a folder / folders over {FOLDER_MODULES}", *CHANGES],
           [_row79(name, fig) for name, fig in figs.items()])
    for name, fig in figs.items():
        print(f"\n{name}:\n  modules over 500 lines {fig.library_modules_over_500}\n  classes over 300 lines "
              f"{fig.library_classes_over_300}\n  functions over 80 lines {fig.library_functions_over_80}\n"
              f"  descriptions not standing alone {fig.settings_not_standalone}\n"
              f"  settings without a description: {len(fig.settings_undescribed)}\n"
              f"  folders over {FOLDER_MODULES} modules {fig.folders_over_12}")
        for change in CHANGES:
            if fig.change_files.get(change) is None:
                print(f"  {change}: UNRESOLVED (add a layout to CHANGES): {fig.change_unresolved.get(change)}")
            else:
                print(f"  {change} (layout {fig.change_layout[change]}): {fig.change_opened[change]}")
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps({k: dataclasses.asdict(v) for k, v in figs.items()}, indent=1) + "\n")
    unresolved = any(v is None for f in figs.values() for v in f.change_files.values())
    return 1 if unresolved or any(f.tests_not_judged for f in figs.values()) else 0


if __name__ == "__main__":
    sys.exit(main())
