"""Helpers for benchmarks: results table on stdout, JSON in out/bench/."""

from __future__ import annotations

import json
import os
import platform
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "out" / "bench"
SEVEN_SCENES = ROOT.parent / "shared" / "data" / "7scenes-redkitchen"
INPUTS = OUT / "inputs"  # recordings and maps the benchmarks make for themselves (cached)


def litevloc(*args: str) -> None:
    """Run one `litevloc` command in a child process (its output goes to the terminal); fail loudly."""
    t0 = time.perf_counter()
    print(f"$ litevloc {' '.join(args)}", flush=True)
    r = subprocess.run([sys.executable, "-m", "litevloc.cli.main", *args])
    if r.returncode != 0:
        raise SystemExit(f"`litevloc {' '.join(args)}` failed with exit code {r.returncode}")
    print(f"  ({time.perf_counter() - t0:.0f} s)", flush=True)


def office_inputs(world: str = "office", config: str = "default") -> tuple[Path, Path]:
    """(map folder, query recording) of a simulated world, made when absent and cached under
    out/bench/inputs/WORLD: the mapping pass (`sim record --pass map --seed 0`, as `litevloc demo`
    records it) built into a map, and the query pass (`sim record --pass query --seed 0`: another
    route and lighting). Each is written under a temporary name and renamed when complete, so an
    interrupted run leaves nothing that looks finished. Delete the folder to rebuild."""
    d = INPUTS / world
    d.mkdir(parents=True, exist_ok=True)
    map_dir, query = d / "map", d / "query.mcap"
    cfg = ("--config", config)
    if not (map_dir / "manifest.json").is_file():
        map_rec, tmp = d / "map.mcap", d / "map.partial"
        if not map_rec.is_file():
            litevloc("sim", "record", world, "--pass", "map", "--seed", "0", "-o", str(d / "map.partial.mcap"), *cfg)
            (d / "map.partial.mcap").replace(map_rec)
        shutil.rmtree(tmp, ignore_errors=True)
        litevloc("map", "build", str(map_rec), "-o", str(tmp), "--force", *cfg)
        shutil.rmtree(map_dir, ignore_errors=True)
        tmp.replace(map_dir)
    if not query.is_file():
        litevloc("sim", "record", world, "--pass", "query", "--seed", "0", "-o", str(d / "query.partial.mcap"), *cfg)
        (d / "query.partial.mcap").replace(query)
    return map_dir, query


def require_7scenes() -> Path:
    if not (SEVEN_SCENES / "frame-000000.color.jpg").is_file():
        raise SystemExit(f"benchmark needs the 7-Scenes data at {SEVEN_SCENES}")
    return SEVEN_SCENES


def print_table(title: str, header: list[str], rows: list[list[Any]]) -> None:
    cells = [[str(c) if not isinstance(c, float) else f"{c:.3g}" for c in r] for r in rows]
    widths = [max([len(h), *(len(r[i]) for r in cells)]) for i, h in enumerate(header)]
    print(f"\n{title}")
    print("  ".join(h.ljust(w) for h, w in zip(header, widths, strict=True)))
    print("  ".join("-" * w for w in widths))
    for r in cells:
        print("  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)))


def _cpu_model() -> str:
    try:
        lines = Path("/proc/cpuinfo").read_text().splitlines()
    except OSError:
        return platform.processor() or platform.machine()
    return next((ln.split(":", 1)[1].strip() for ln in lines if ln.startswith("model name")), platform.machine())


def run_meta() -> dict[str, Any]:
    """The machine and how busy it was (a shared machine's timings say so), the command, when."""
    return {"machine": platform.machine(), "python": platform.python_version(), "time": time.strftime("%FT%T%z"),
            "cpu": _cpu_model(), "cpus": os.cpu_count(), "load_avg": os.getloadavg()[0],
            "command": " ".join([Path(sys.argv[0]).name, *sys.argv[1:]])}


def json_path(name: str) -> Path:
    """out/bench/NAME.json, or NAME itself where it ends in .json (a path, relative to the working directory)."""
    return Path(name) if name.endswith(".json") else OUT / f"{name}.json"


def write_json(name: str, data: dict[str, Any]) -> Path:
    """Write `data` with the run's metadata to `json_path(name)`."""
    path = json_path(name)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"meta": run_meta(), **data}, indent=2, default=float) + "\n")
    print(f"\nwrote {path}")
    return path


if __name__ == "__main__":  # `python bench/_common.py office-inputs [WORLD]`: make the cached inputs now
    if len(sys.argv) < 2 or sys.argv[1] != "office-inputs":
        raise SystemExit("usage: python bench/_common.py office-inputs [WORLD]")
    m, q = office_inputs(*sys.argv[2:3])
    print(f"map {m}\nquery {q}")
