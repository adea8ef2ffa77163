"""Layers that point one way: `base` <- `hw`, `models`, `config`; `pipelines` -> `models`, `base`;
`sim` -> `pipelines`, `hw`, `base`; `runtime` above them; `experiments` (the benchmarks' logic)
above `runtime`, imported only by the command line (`cli`, the top layer) and `bench/`. Inside
`runtime`, the transport is the bottom subsystem, the service and the planner's node sit on it,
and the offline tools on all three.

`config` imports no algorithm or hardware module, `hw` (drivers and file formats) imports only
`base`, the simulator imports neither the configuration nor the runtime, and `base` imports no
other LiteVLoc package. The static checks read the sources; the
dynamic ones import `litevloc.config` in a fresh interpreter and look at `sys.modules`.
"""

from __future__ import annotations

import ast
import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
# Heavy or hardware modules the configuration must not load.
HEAVY = ("cv2", "scipy", "rosbags", "gtsam", "onnxruntime", "zenoh", "matplotlib", "skimage", "depthai", "mcap",
         "litevloc.hw", "litevloc.models", "litevloc.runtime", "litevloc.sim")
def _imports(path: Path) -> set[str]:
    mods: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            mods.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module:
            mods.add(node.module)
    return mods


def _package_imports(pkg: str) -> dict[str, set[str]]:
    return {str(p.relative_to(ROOT)): _imports(p) for p in sorted((ROOT / pkg).rglob("*.py"))}


def _offending(pkg: str, forbidden: tuple[str, ...]) -> dict[str, list[str]]:
    out = {}
    for path, mods in _package_imports(pkg).items():
        bad = sorted(m for m in mods if any(m == f or m.startswith(f + ".") for f in forbidden))
        if bad:
            out[path] = bad
    return out


def test_base_imports_no_other_litevloc_package() -> None:
    assert _offending("base", ("litevloc.config", "litevloc.hw", "litevloc.sim", "litevloc.models",
                               "litevloc.pipelines", "litevloc.runtime")) == {}


def test_hw_imports_only_base() -> None:
    assert _offending("hw", ("litevloc.config", "litevloc.runtime", "litevloc.pipelines", "litevloc.models",
                             "litevloc.sim")) == {}


def test_sim_imports_no_config_or_runtime() -> None:
    assert _offending("sim", ("litevloc.config", "litevloc.runtime")) == {}


def test_config_imports_only_base() -> None:
    assert _offending("config", ("litevloc.hw", "litevloc.sim", "litevloc.models", "litevloc.pipelines",
                                 "litevloc.runtime")) == {}


def _modules_loaded_by_config(preload: tuple[str, ...]) -> list[str]:
    code = (
        "import importlib, json, sys\n"
        f"for m in {list(preload)!r}: importlib.import_module(m)\n"
        "before = set(sys.modules)\n"
        "import litevloc.config\n"
        "print(json.dumps(sorted(set(sys.modules) - before)))\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True)
    return list(json.loads(r.stdout))


def _heavy(mods: list[str]) -> list[str]:
    return sorted(m for m in mods if any(m == h or m.startswith(h + ".") for h in HEAVY)
                  or m.startswith("litevloc.pipelines"))


def test_import_config_loads_no_heavy_module() -> None:
    loaded = _modules_loaded_by_config(())
    assert "litevloc.config.schema" in loaded
    assert _heavy(loaded) == []


def test_only_the_command_line_imports_experiments() -> None:
    for pkg in ("base", "config", "hw", "sim", "models", "pipelines"):
        assert _offending(pkg, ("litevloc.experiments",)) == {}, pkg
    assert _offending("runtime", ("litevloc.experiments",)) == {}


def test_nothing_below_the_command_line_imports_it() -> None:
    for pkg in ("base", "config", "hw", "sim", "models", "pipelines", "runtime", "experiments"):
        assert _offending(pkg, ("litevloc.cli",)) == {}, pkg


# runtime's subsystems: what each may import of the others (the shared modules at runtime/'s top,
# metrics, sources, model glue, child processes, import none of them)
RUNTIME_SUBSYSTEMS = ("service", "transport", "planner", "maps", "tools")
RUNTIME_MAY_IMPORT = {
    "transport": (),
    "service": ("transport",),
    "planner": ("transport",),
    "maps": ("transport",),
    "tools": ("service", "transport", "planner", "maps"),
}


def test_runtime_subsystems_point_one_way() -> None:
    for sub, allowed in RUNTIME_MAY_IMPORT.items():
        forbidden = tuple(f"litevloc.runtime.{o}" for o in RUNTIME_SUBSYSTEMS if o != sub and o not in allowed)
        assert _offending(f"runtime/{sub}", forbidden) == {}, sub
    shared = {p: m for p, m in _offending("runtime", tuple(f"litevloc.runtime.{o}" for o in RUNTIME_SUBSYSTEMS)).items()
              if p.count("/") == 1}
    assert shared == {}


def test_runtime_holds_only_its_subsystems_and_the_shared_modules() -> None:
    """A new runtime module goes into the subsystem it belongs to, not back into a flat folder."""
    top = sorted(p.name for p in (ROOT / "runtime").glob("*.py"))
    assert top == ["__init__.py", "child_processes.py", "metrics.py", "recording_process.py", "sources.py",
                   "vloc_models.py"]
    assert sorted(p.name for p in (ROOT / "runtime").iterdir() if p.is_dir() and p.name != "__pycache__") == \
        sorted(RUNTIME_SUBSYSTEMS)


def test_experiments_do_not_import_the_command_line() -> None:
    assert _offending("experiments", ("litevloc.cli",)) == {}


def test_bench_scripts_import_no_command_line_module() -> None:
    """Benchmarks call library functions (`litevloc.experiments`, ...), never a CLI module (they
    may run the `litevloc` program as a child process, as a user would)."""
    assert _offending("bench", ("litevloc.cli",)) == {}
