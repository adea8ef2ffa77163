"""The aarch64 (Jetson) build checked on this x86 machine: the runtime's own aarch64 wheels run
under qemu user-mode emulation and must compute what x86 computes (issue 75 item 5).

Steps (each shows its progress; the slow ones print a line every 30 s):

1. qemu-user-static and an arm64 sysroot (Debian's arm64 Python 3.11 and its libraries,
   `experiments/aarch64.py` SYSROOT_PACKAGES, unpacked with `dpkg -x`) under `.cache/aarch64/`,
   with an Orin `/proc/cpuinfo` in it (onnxruntime's CPU probe crashes on the host's x86 text).
   Made once; apt-get when qemu or the arm64 packages are missing (root only).
2. The project wheel built here; its runtime requirements (from the wheel's metadata, plus the
   `cpu` extra where it has one) installed as manylinux aarch64 wheels with `pip --target
   --platform`, pinned to this environment's versions (both sides run the same releases); the
   project wheel on top (`--no-deps`). The `.so` files' NEEDED libraries are checked against
   the sysroot and the wheels, and every runtime dependency is imported under emulation.
3. An x86 map of 7-Scenes redkitchen (README's quick start: frames 0:500:5, `--config
   7scenes`), rebuilt every run with the current model cache ($LITEVLOC_MODEL_CACHE).
4. `litevloc localize` on the query frames (`--frames`, default 500:650:50, 3 frames: one
   global localization, then two local ones) under x86 and under emulation, same map, same settings:
   the 7scenes preset with the second look off (`localization.second_look.candidates=0`): a
   look costs minutes under emulation (full-resolution ALIKED and LightGlue on 2048 points);
   the look's extractor is compared below on its own. Poses must agree within `--tol-m` (1 cm).
5. Every model the runtime uses (`litevloc models list`: the default exports and the config's:
   ALIKED n16 and t16, the second look's ALIKED, LightGlue in full and the adaptive LightGlue's 19
   parts, EfficientNet-GeM) on fixed inputs (7-Scenes frames 500 and 510; LightGlue on the
   `LIGHTGLUE_POINTS` strongest points of each, each adaptive part on the x86 outputs of the part
   before) under x86 and emulated onnxruntime, through the runtime's session options: float
   outputs within 1e-3 of the output's largest value (+1e-5), match indices equal on >= 99 % of
   the points, keypoints paired by position (within 0.01 px) so a different choice among equal
   scores at the top-k cut is told from a wrong value.

Table on stdout, JSON in out/bench/aarch64.json (the figures table's "aarch64 build under
emulation" row), run files in out/aarch64/. Exit 0 when everything agrees, 1 when something
differs, 2 when qemu, apt-get, the data or a model is missing (one line).

    python tools/aarch64_check.py [--frames 500:650:50] [--tol-m 0.01] [--skip-models] [--skip-localize]
    make aarch64-check
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import subprocess
import sys
import threading
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import asdict
from importlib import metadata
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))

from _common import SEVEN_SCENES, print_table, write_json  # noqa: E402

from litevloc.base.errors import LiteVLocError  # noqa: E402
from litevloc.experiments import aarch64 as a64  # noqa: E402
from litevloc.experiments import model_conformance as mc  # noqa: E402

CACHE = ROOT / ".cache" / "aarch64"
OUT = ROOT / "out" / "aarch64"
SECOND_LOOK_OFF = "localization.second_look.candidates=0"
# runtime requirement -> its import name, for the emulated import check (others: name with _)
IMPORT_NAMES = {"opencv-python-headless": "cv2", "eclipse-zenoh": "zenoh", "pyyaml": "yaml",
                "scikit-image": "skimage"}
# LightGlue's inputs: the strongest points of each image (its cost grows with their square; 512
# points: ~3 min for the nine layers under emulation on two shared cores)
LIGHTGLUE_POINTS = 256
QEMU_CPU = "cortex-a76"  # ARMv8.2 with dotprod and fp16 and no SVE, like the Orin's Cortex-A78AE


class CheckUnavailable(LiteVLocError):
    """What the check needs (qemu, apt-get, root, the 7-Scenes data, a model) is missing here."""


class StepFailed(LiteVLocError):
    """A command of the check failed (its output is above)."""


def log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


@contextmanager
def heartbeat(what: str, every_s: float = 30.0) -> Iterator[None]:
    """Print `what ... N s` every `every_s` seconds while the block runs."""
    stop = threading.Event()
    t0 = time.perf_counter()

    def beat() -> None:
        while not stop.wait(every_s):
            log(f"    ... {what}: {time.perf_counter() - t0:.0f} s")

    th = threading.Thread(target=beat, daemon=True)
    th.start()
    try:
        yield
    finally:
        stop.set()
        th.join()


def run(cmd: Sequence[str], what: str, env: dict[str, str] | None = None, quiet: bool = False,
        cwd: Path | None = None, timed: bool = True) -> str:
    """Run `cmd` (its output to the terminal, or captured and shown only on failure when `quiet`),
    then print its seconds (`timed`); StepFailed naming `what` on a non-zero exit. Returns the
    captured output ('' when not quiet)."""
    t0 = time.perf_counter()
    with heartbeat(what):
        r = subprocess.run(list(cmd), env=env, cwd=cwd, text=True,
                           stdout=subprocess.PIPE if quiet else None, stderr=subprocess.STDOUT if quiet else None)
    if r.returncode != 0:
        if quiet and r.stdout:
            print(r.stdout[-4000:], file=sys.stderr)
        raise StepFailed(f"{what} failed (exit {r.returncode}): {' '.join(cmd)[:300]}")
    if timed:
        log(f"    {what}: {time.perf_counter() - t0:.0f} s")
    return r.stdout or ""


# --- 1. qemu and the sysroot -------------------------------------------------------------------


def _apt(*args: str) -> None:
    if shutil.which("apt-get") is None:
        raise CheckUnavailable("apt-get is not available: install qemu-user-static and Debian arm64 packages by hand")
    if os.geteuid() != 0:
        raise CheckUnavailable(f"`apt-get {' '.join(args)}` needs root: run the check as root, or do it once by hand")
    env = {**os.environ, "DEBIAN_FRONTEND": "noninteractive"}
    run(["apt-get", *args], f"apt-get {args[0]}", env=env, quiet=True)


def ensure_qemu() -> str:
    """The path of qemu-aarch64-static, installed with apt-get when missing."""
    q = shutil.which("qemu-aarch64-static")
    if q is None:
        log("  qemu-aarch64-static missing: apt-get install qemu-user-static")
        _apt("update", "-qq")
        _apt("install", "-y", "-qq", "qemu-user-static")
        q = shutil.which("qemu-aarch64-static")
        if q is None:
            raise CheckUnavailable("apt-get installed qemu-user-static but qemu-aarch64-static is not on PATH")
    return q


def ensure_sysroot(n_cpus: int) -> Path:
    """`.cache/aarch64/sysroot`: the Debian arm64 packages unpacked, and `sysroot_files`; remade
    when the package list changes (a stamp file records it)."""
    root, stamp = CACHE / "sysroot", CACHE / "sysroot.packages"
    want = "\n".join(a64.SYSROOT_PACKAGES) + "\n"
    if not (stamp.is_file() and stamp.read_text() == want and (root / "usr/bin/python3.11").is_file()):
        if shutil.which("dpkg") is None:
            raise CheckUnavailable("dpkg is not available: the sysroot is made from Debian's arm64 packages")
        foreign = subprocess.run(["dpkg", "--print-foreign-architectures"], capture_output=True, text=True).stdout
        if "arm64" not in foreign.split():
            log("  adding Debian's arm64 architecture (dpkg --add-architecture arm64, apt-get update)")
            if os.geteuid() != 0:
                raise CheckUnavailable("`dpkg --add-architecture arm64` needs root")
            run(["dpkg", "--add-architecture", "arm64"], "dpkg --add-architecture", quiet=True)
            _apt("update", "-qq")
        debs = CACHE / "debs"
        shutil.rmtree(debs, ignore_errors=True)
        debs.mkdir(parents=True)
        log(f"  downloading {len(a64.SYSROOT_PACKAGES)} Debian arm64 packages")
        if shutil.which("apt-get") is None:
            raise CheckUnavailable("apt-get is not available: the sysroot is made from Debian's arm64 packages")
        run(["apt-get", "download", "-q", *(f"{p}:arm64" for p in a64.SYSROOT_PACKAGES)], "apt-get download",
            cwd=debs, quiet=True)
        tmp = CACHE / "sysroot.partial"
        shutil.rmtree(tmp, ignore_errors=True)
        for deb in sorted(debs.glob("*.deb")):
            run(["dpkg", "-x", str(deb), str(tmp)], f"dpkg -x {deb.name}", quiet=True, timed=False)
        shutil.rmtree(root, ignore_errors=True)
        tmp.replace(root)
        stamp.write_text(want)
    for rel, text in a64.sysroot_files(n_cpus).items():
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_text(text)
    return root


# --- 2. the wheels -----------------------------------------------------------------------------


def build_project_wheel() -> Path:
    d = CACHE / "wheel"
    shutil.rmtree(d, ignore_errors=True)
    run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--disable-pip-version-check", "-w", str(d),
         str(ROOT)], "project wheel", quiet=True)
    (whl,) = d.glob("litevloc-*.whl")
    return whl


def wheel_metadata(whl: Path) -> str:
    import zipfile

    with zipfile.ZipFile(whl) as z:
        name = next(n for n in z.namelist() if n.endswith(".dist-info/METADATA"))
        return z.read(name).decode()


def host_versions() -> dict[str, str]:
    """{canonical name: version} of this (x86) environment's distributions."""
    return {a64.canonical_name(d.metadata["Name"]): d.version for d in metadata.distributions()
            if d.metadata["Name"]}


def ensure_site(whl: Path) -> tuple[Path, list[str]]:
    """`.cache/aarch64/site-HASH`: the pinned aarch64 requirements (HASH of their list: reused while
    it holds), the project wheel reinstalled on top every run. Returns (folder, requirements)."""
    reqs = a64.pinned(a64.requirements_from_metadata(wheel_metadata(whl)), host_versions())
    key = hashlib.sha256("\n".join([*reqs, *a64.PIP_PLATFORMS]).encode()).hexdigest()[:12]
    site = CACHE / f"site-{key}"
    pip = [sys.executable, "-m", "pip", "install", "-q", "--disable-pip-version-check", "--target"]
    plat = [a for p in a64.PIP_PLATFORMS for a in ("--platform", p)]
    plat += ["--python-version", "3.11", "--implementation", "cp", "--only-binary=:all:"]
    if not (site / ".complete").is_file():
        for old in CACHE.glob("site-*"):
            shutil.rmtree(old, ignore_errors=True)
        tmp = CACHE / f"site-{key}.partial"
        shutil.rmtree(tmp, ignore_errors=True)
        log(f"  installing {len(reqs)} runtime requirements as aarch64 wheels: {' '.join(reqs)}")
        run([*pip, str(tmp), *plat, *reqs], "pip install --platform aarch64", quiet=True)
        tmp.replace(site)
        (site / ".complete").write_text("\n".join(reqs) + "\n")
    for old in [*site.glob("litevloc"), *site.glob("litevloc-*.dist-info")]:
        shutil.rmtree(old)
    run([*pip, str(site), *plat, "--no-deps", str(whl)], "project wheel into the aarch64 site", quiet=True)
    return site, reqs


def library_check(sysroot: Path, site: Path) -> dict[str, list[str]]:
    """NEEDED libraries of the wheels' `.so` files that neither the sysroot nor a wheel provides."""
    if shutil.which("readelf") is None:
        log("  readelf missing (binutils): the NEEDED-library scan is skipped")
        return {}
    sos = [p for p in site.rglob("*.so*") if p.is_file() and not p.is_symlink()]
    provided = {p.name for base in (sysroot, site) for p in base.rglob("*.so*")}
    needed: dict[str, list[str]] = {}
    for so in sos:
        r = subprocess.run(["readelf", "-d", str(so)], capture_output=True, text=True)
        needed[str(so.relative_to(site))] = a64.needed_libraries(r.stdout)
    return a64.unresolved_libraries(needed, provided)


class Emulator:
    """The emulated aarch64 Python: qemu-aarch64-static -cpu QEMU_CPU -L SYSROOT SYSROOT/usr/bin/python3.11."""

    def __init__(self, qemu: str, sysroot: Path, site: Path) -> None:
        self.cmd = [qemu, "-cpu", QEMU_CPU, "-L", str(sysroot), str(sysroot / "usr/bin/python3.11")]
        self.env = {**os.environ, "PYTHONPATH": str(site), "PYTHONNOUSERSITE": "1", "PYTHONDONTWRITEBYTECODE": "1"}
        self.env.pop("VIRTUAL_ENV", None)

    def python(self, args: Sequence[str], what: str, quiet: bool = False) -> str:
        return run([*self.cmd, *args], what, env=self.env, quiet=quiet)


def import_check(emu: Emulator, reqs: Sequence[str]) -> dict[str, Any]:
    """Import every runtime requirement and the CLI under emulation; what the process reports."""
    mods = [IMPORT_NAMES.get(a64.canonical_name(a64.requirement_name(r)),
                             a64.canonical_name(a64.requirement_name(r)).replace("-", "_")) for r in reqs]
    code = ("import importlib, json, platform, sys, time\n"
            "t = time.perf_counter()\n"
            f"mods = {mods!r}\n"
            "for m in mods: importlib.import_module(m)\n"
            "import litevloc.cli.main\n"
            "import onnxruntime\n"
            "print(json.dumps({'machine': platform.machine(), 'python': platform.python_version(),\n"
            "  'onnxruntime': onnxruntime.__version__, 'providers': onnxruntime.get_available_providers(),\n"
            "  'modules': mods, 'import_s': time.perf_counter() - t}))\n")
    out = emu.python(["-c", code], "emulated imports", quiet=True)
    info: dict[str, Any] = json.loads(out.strip().splitlines()[-1])
    if info["machine"] != "aarch64":
        raise StepFailed(f"the emulated Python says it runs on {info['machine']}, not aarch64")
    return info


# --- 3-4. map and localization -----------------------------------------------------------------


def litevloc_cmd(args: Sequence[str]) -> list[str]:
    return ["-m", "litevloc.cli.main", *args]


def build_map(data: Path) -> Path:
    out = OUT / "map"
    shutil.rmtree(out, ignore_errors=True)
    run([sys.executable, *litevloc_cmd(["map", "build", str(data), "--frames", "0:500:5", "-o", str(out),
                                        "--config", "7scenes", "--force"])], "x86 map build", quiet=True)
    return out


def localize_args(map_dir: Path, data: Path, frames: str, side: str) -> list[str]:
    d = OUT / side
    return litevloc_cmd(["localize", str(map_dir), str(data), "--frames", frames, "--config", "7scenes",
                         "--set", SECOND_LOOK_OFF, "-o", str(d / "vloc.txt"), "--json", str(d / "vloc.json")])


# --- 5. model inputs ---------------------------------------------------------------------------


def check_models() -> None:
    """CheckUnavailable naming `litevloc models export` where a model of `mc.model_ids` is missing or
    stale in the model cache (before minutes of work that would need it)."""
    from litevloc.config import load_config
    from litevloc.models.registry import ModelError, locate

    cfg = load_config("7scenes").models
    for mid in mc.model_ids():
        try:
            locate(mid, cfg)
        except ModelError as exc:
            raise CheckUnavailable(str(exc)) from exc


# --- the check ---------------------------------------------------------------------------------


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", type=Path, default=SEVEN_SCENES, help="the 7-Scenes redkitchen folder")
    ap.add_argument("--frames", default="500:650:50", help="query frames of the localization (a slice)")
    ap.add_argument("--tol-m", type=float, default=0.01, help="largest position difference of a pose (m)")
    ap.add_argument("--skip-localize", action="store_true", help="only the models")
    ap.add_argument("--skip-models", action="store_true", help="only the localization")
    ap.add_argument("--name", default="aarch64", help="JSON out/bench/NAME.json")
    args = ap.parse_args(argv)
    try:
        return check(args)
    except LiteVLocError as exc:
        print(f"aarch64 check: {exc}", file=sys.stderr)
        return 2 if isinstance(exc, CheckUnavailable) else 1


def check(args: argparse.Namespace) -> int:
    t_start = time.perf_counter()
    data: Path = args.data
    if not (data / "frame-000000.color.jpg").is_file():
        raise CheckUnavailable(f"the check needs the 7-Scenes data at {data} (see its DATA.md)")
    check_models()
    n_steps = 6
    n_cpus = os.cpu_count() or 1
    log(f"[1/{n_steps}] qemu and the arm64 sysroot ({CACHE})")
    qemu = ensure_qemu()
    sysroot = ensure_sysroot(n_cpus)
    log(f"[2/{n_steps}] aarch64 wheels")
    site, reqs = ensure_site(build_project_wheel())
    unresolved = library_check(sysroot, site)
    for lib, files in unresolved.items():
        log(f"  NEEDED {lib} is in neither the sysroot nor a wheel (needed by {', '.join(files[:3])})")
    emu = Emulator(qemu, sysroot, site)
    env_info = import_check(emu, reqs)
    log(f"  emulated {env_info['machine']} Python {env_info['python']}, onnxruntime {env_info['onnxruntime']}: "
        f"{len(env_info['modules'])} runtime modules import ({env_info['import_s']:.0f} s)")
    result: dict[str, Any] = {"requirements": reqs, "sysroot_packages": list(a64.SYSROOT_PACKAGES),
                              "qemu_cpu": QEMU_CPU, "unresolved_libraries": unresolved, "emulated": env_info,
                              "settings": {"config": "7scenes", "set": [SECOND_LOOK_OFF], "frames": args.frames,
                                           "map_frames": "0:500:5"}}
    ok = not unresolved
    if not args.skip_localize:
        log(f"[3/{n_steps}] x86 map of {data.name} (frames 0:500:5)")
        map_dir = build_map(data)
        log(f"[4/{n_steps}] localize {args.frames}: x86, then aarch64 under emulation (minutes)")
        t0 = time.perf_counter()
        run([sys.executable, *localize_args(map_dir, data, args.frames, "x86")], "x86 localize")
        t_x86 = time.perf_counter() - t0
        t0 = time.perf_counter()
        emu.python(localize_args(map_dir, data, args.frames, "aarch64"), "aarch64 localize")
        t_arm = time.perf_counter() - t0
        ref = a64.parse_tum((OUT / "x86" / "vloc.txt").read_text())
        got = a64.parse_tum((OUT / "aarch64" / "vloc.txt").read_text())
        pd = a64.compare_poses(ref, got)
        js = {s: json.loads((OUT / s / "vloc.json").read_text()) for s in ("x86", "aarch64")}
        same_counts = all(js["x86"][k] == js["aarch64"][k] for k in ("queries", "accepted", "global", "local"))
        loc_ok = pd.passed(args.tol_m) and same_counts
        ok = ok and loc_ok
        result["localize"] = {**asdict(pd), "tol_m": args.tol_m, "passed": loc_ok, "x86_s": t_x86, "aarch64_s": t_arm,
                              "counts": {s: {k: js[s][k] for k in ("queries", "accepted", "global", "local")}
                                         for s in js}}
        print_table(f"localize {args.frames} ({pd.frames_both} poses both accepted; x86 {t_x86:.0f} s, "
                    f"aarch64 emulated {t_arm:.0f} s)", ["t s", "position diff m", "rotation diff deg"],
                    [[f"{t:.3f}", f"{m:.2e}", f"{d:.2e}"] for t, m, d in pd.per_frame])
        print(f"accepted x86 {js['x86']['accepted']}/{js['x86']['queries']}, aarch64 "
              f"{js['aarch64']['accepted']}/{js['aarch64']['queries']}; max {pd.max_m:.2e} m / {pd.max_deg:.2e} deg "
              f"(tolerance {args.tol_m} m): {'PASS' if loc_ok else 'FAIL'}")
    if not args.skip_models:
        log(f"[5/{n_steps}] model inputs (x86) and the models under x86")
        inputs = OUT / "model-inputs"
        try:
            index = mc.prepare_model_inputs(data, inputs, lightglue_points=LIGHTGLUE_POINTS)
        except mc.ModelInputsError as exc:
            raise CheckUnavailable(str(exc)) from exc
        worker = ["-m", "litevloc.experiments.model_conformance", "run-models", str(inputs)]
        run([sys.executable, *worker, str(OUT / "x86" / "models")], "x86 models", quiet=True)
        log(f"[6/{n_steps}] the {len(index)} models (and parts) under emulation")
        emu.python([*worker, str(OUT / "aarch64" / "models")], "aarch64 models")
        diffs = mc.compare_models(index, OUT / "x86" / "models", OUT / "aarch64" / "models")
        models_ok = all(d.passed for d in diffs)
        ok = ok and models_ok
        timings = {s: json.loads((OUT / s / "models" / "timings.json").read_text()) for s in ("x86", "aarch64")}
        result["models"] = {"count": len(index), "tolerance": asdict(mc.Tolerance()), "passed": models_ok,
                            "outputs": [asdict(d) for d in diffs], "seconds": timings}
        print_table("model outputs, x86 vs aarch64 (same inputs)", ["model", "output", "max abs diff", "of max |x86|",
                                                                    "agree", "ok", "note"],
                    [[d.model, d.output, f"{d.max_abs:.2e}", f"{d.scale:.3g}", f"{100 * d.agree:.1f} %",
                      "yes" if d.passed else "NO", d.note] for d in diffs])
        worst = max((d.max_abs / d.scale for d in diffs if d.scale > 0), default=0.0)
        result["models"]["worst_relative"] = worst
        print(f"{sum(d.passed for d in diffs)}/{len(diffs)} outputs of {len(index)} models within tolerance, worst "
              f"{worst:.1e} of the output's largest value: {'PASS' if models_ok else 'FAIL'}")
    result["passed"] = ok
    result["wall_s"] = time.perf_counter() - t_start
    write_json(args.name, result)
    print(f"aarch64 check: {'PASS' if ok else 'FAIL'} in {result['wall_s'] / 60:.1f} min")
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
