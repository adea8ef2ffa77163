"""Issue 44's before/after table: README size, modules over 500 lines, functions over 100 lines,
settings reachable from a configuration file, shims, duplicate blocks, tests that localize
their own mapping frames (`litevloc.experiments.codebase`), for the working tree and for any
commits given (exported with `git archive` to a temporary folder).

    python bench/codebase.py [--before bb82192] [--json out/bench/codebase.json]
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

from litevloc.experiments.codebase import CodebaseFigures, measure

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


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--before", nargs="*", default=["bb82192"], help="commits to measure beside the working tree")
    ap.add_argument("--json", type=Path, default=ROOT / "out" / "bench" / "codebase.json")
    args = ap.parse_args()
    figs: dict[str, CodebaseFigures] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for commit in args.before:
            figs[commit] = measure(_export(commit, Path(tmp)))
    figs["working tree"] = measure(ROOT)
    header = ["tree", "README", "modules > 500 lines", "functions > 100 lines", "settings reachable",
              "shim modules / `import X as X` / imports through another module",
              "duplicate pairs in the library (not boilerplate)", "tests localizing their own mapping frames"]
    print("| " + " | ".join(header) + " |\n|" + "---|" * len(header))
    for name, fig in figs.items():
        print("| " + " | ".join(_row(name, fig)) + " |")
    for name, fig in figs.items():
        through = fig.imports_through_another_module
        print(f"\n{name}: modules over 500 lines {fig.modules_over_500}; functions over 100 lines "
              f"{fig.functions_over_100}; unreachable settings classes {fig.settings_classes_unreachable}; "
              f"shim modules {fig.shim_modules}; imports through another module {through[:12]}"
              f"{' ...' if len(through) > 12 else ''}; tests localizing their own frames "
              f"{fig.tests_localizing_own_frames}")
        if fig.tests_not_judged:
            print(f"  NOT JUDGED (add them to LOCALIZATION_TESTS): {fig.tests_not_judged}")
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps({k: dataclasses.asdict(v) for k, v in figs.items()}, indent=1) + "\n")
    return 1 if any(f.tests_not_judged for f in figs.values()) else 0


if __name__ == "__main__":
    sys.exit(main())
