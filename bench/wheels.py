"""Does LiteVLoc install on the robot's platform from binary wheels alone? Resolved here, for each target.

For every target (Python version x platform; default: Jetson Orin / JetPack 6 = cp310 linux-aarch64
glibc 2.35, Jetson Thor / JetPack 7 = cp312 linux-aarch64 glibc 2.39, and x86_64 cp310/cp311/cp312):

1. `uv pip compile` resolves pyproject.toml with the extra (default `cpu`) for that target with
   binary wheels only. uv evaluates the environment markers (gtsam's pin on Python 3.10) for the
   target; `pip download --platform` cannot: pip evaluates markers against the interpreter that
   runs it, so from this machine's 3.11 it would pick the 3.11 branch of every marker.
2. `pip download --no-deps --only-binary=:all: --platform ... --python-version ...` fetches each
   pinned distribution, as pip on the robot would, and the project's own wheel (built here).
3. It reports the wheels, their size, the versions that matter (gtsam, onnxruntime, numpy) and
   every pre-release among them (allowed only where pyproject.toml pins it by name).

A table on stdout, JSON in out/bench/wheels.json. Needs the package registry; downloads are cached
under out/wheels/ (about 300 MB per target on a first run).

    python bench/wheels.py [--targets cp310-aarch64 cp312-aarch64] [--extra cpu] [--name wheels]
"""

from __future__ import annotations

import argparse
import re
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import cast

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import print_table, write_json

ROOT = Path(__file__).resolve().parents[1]
CACHE = ROOT / "out" / "wheels"


@dataclass(frozen=True)
class Target:
    """A robot or desktop platform: CPython version, machine, newest glibc its OS ships."""

    name: str
    python: str  # "3.10"
    machine: str  # aarch64 | x86_64
    glibc: tuple[int, int]
    who: str

    @property
    def pip_platforms(self) -> list[str]:
        """Every manylinux tag this glibc accepts, newest first (pip matches tags exactly)."""
        tags = [f"manylinux_2_{minor}_{self.machine}" for minor in range(self.glibc[1], 16, -1)]
        return [*tags, f"manylinux2014_{self.machine}"]

    @property
    def uv_platform(self) -> str:
        return f"{self.machine}-manylinux_2_{self.glibc[1]}"


TARGETS = {t.name: t for t in (
    Target("cp310-aarch64", "3.10", "aarch64", (2, 35), "Jetson Orin, JetPack 6 (Ubuntu 22.04, ROS 2 Humble)"),
    Target("cp312-aarch64", "3.12", "aarch64", (2, 39), "Jetson Thor, JetPack 7 (Ubuntu 24.04, ROS 2 Jazzy)"),
    Target("cp311-aarch64", "3.11", "aarch64", (2, 36), "Debian 12 arm64 (the qemu check's sysroot)"),
    Target("cp310-x86_64", "3.10", "x86_64", (2, 35), "Ubuntu 22.04 desktop"),
    Target("cp311-x86_64", "3.11", "x86_64", (2, 36), "Debian 12 (this machine, CI)"),
    Target("cp312-x86_64", "3.12", "x86_64", (2, 39), "Ubuntu 24.04 desktop"),
)}
PRE = re.compile(r"\d(a|b|rc|\.dev)\d")


def _run(cmd: list[str]) -> subprocess.CompletedProcess[str]:
    return subprocess.run(cmd, capture_output=True, text=True, check=False)


def _project_wheel() -> Path:
    out = CACHE / "project"
    shutil.rmtree(out, ignore_errors=True)
    proc = _run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation", str(ROOT),
                 "-w", str(out)])
    if proc.returncode:
        raise SystemExit(f"wheels: building the project's wheel failed:\n{proc.stderr[-2000:]}")
    return next(out.glob("litevloc-*.whl"))


def check(target: Target, extra: str, project: Path) -> dict[str, object]:
    """Resolve and download one target; the figures of its row (resolved False with the reason)."""
    work = CACHE / target.name
    work.mkdir(parents=True, exist_ok=True)
    req = work / "requirements.txt"
    t0 = time.perf_counter()
    uv = shutil.which("uv") or str(Path(sys.executable).parent / "uv")
    proc = _run([uv, "pip", "compile", str(ROOT / "pyproject.toml"), "--extra", extra, "--python-version",
                 target.python, "--python-platform", target.uv_platform, "--only-binary", ":all:", "--no-header",
                 "--no-annotate", "-q", "-o", str(req)])
    if proc.returncode:
        return {"target": target.name, "who": target.who, "resolved": False,
                "reason": proc.stderr.strip().splitlines()[-1] if proc.stderr.strip() else "uv failed"}
    pins = dict(line.split("==", 1) for line in req.read_text().splitlines() if "==" in line)
    wheels = work / "wheels"
    cmd = [sys.executable, "-m", "pip", "download", "-q", "--no-deps", "--only-binary=:all:", "--implementation",
           "cp", "--python-version", target.python, "-d", str(wheels), "-r", str(req), str(project)]
    for tag in target.pip_platforms:
        cmd += ["--platform", tag]
    proc = _run(cmd)
    seconds = time.perf_counter() - t0
    if proc.returncode:
        err = [ln for ln in proc.stderr.splitlines() if ln.startswith("ERROR")]
        return {"target": target.name, "who": target.who, "resolved": False,
                "reason": err[0] if err else proc.stderr[-300:]}
    files = [w for w in wheels.glob("*.whl") if w.name.split("-")[0].lower().replace("_", "-")
             in {p.lower().replace("_", "-") for p in pins} | {"litevloc"}]
    return {"target": target.name, "who": target.who, "resolved": True, "wheels": len(files),
            "mb": round(sum(w.stat().st_size for w in files) / 1e6, 1), "seconds": round(seconds, 1),
            "gtsam": pins.get("gtsam"), "onnxruntime": pins.get("onnxruntime") or pins.get("onnxruntime-gpu"),
            "numpy": pins.get("numpy"), "pre_releases": sorted(f"{p}=={v}" for p, v in pins.items() if PRE.search(v)),
            "pins": pins}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--targets", nargs="+", default=list(TARGETS), choices=list(TARGETS))
    ap.add_argument("--extra", default="cpu", help="the project extra to install with (cpu | gpu | ...)")
    ap.add_argument("--name", default="wheels")
    args = ap.parse_args()
    project = _project_wheel()
    results = []
    for name in args.targets:
        print(f"resolving {name} ...", file=sys.stderr, flush=True)
        results.append(check(TARGETS[name], args.extra, project))
    rows = [[r["target"], "yes" if r["resolved"] else f"NO: {r['reason']}", r.get("wheels", ""), r.get("mb", ""),
             r.get("gtsam", ""), r.get("onnxruntime", ""), r.get("numpy", ""),
             " ".join(cast(list[str], r.get("pre_releases", [])))] for r in results]
    print_table(f"litevloc[{args.extra}] from binary wheels", ["target", "resolves", "wheels", "MB", "gtsam",
                "onnxruntime", "numpy", "pre-releases"], rows)
    write_json(args.name, {"extra": args.extra, "targets": results})
    return 0 if all(r["resolved"] for r in results) else 1


if __name__ == "__main__":
    raise SystemExit(main())
