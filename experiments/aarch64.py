"""The aarch64 check's own logic (`tools/aarch64_check.py` drives it; issue 75 item 5).

The check runs the runtime's aarch64 wheels on an x86 machine under qemu user-mode emulation
(an arm64 Python from Debian's packages in a sysroot folder) and compares what they compute with
the x86 run of the same code on the same inputs. This module holds the parts without qemu:

* the sysroot plan: the Debian arm64 packages (`SYSROOT_PACKAGES`), the ARM `/proc/cpuinfo` the
  sysroot must hold (`cpuinfo_text`: onnxruntime's CPU probe crashes under qemu-user on the
  host's x86 text), and which shared libraries the wheels' `.so` files need that nothing
  provides (`needed_libraries`, `unresolved_libraries`);
* the wheels to install: the runtime requirements read from the project wheel's metadata plus
  its `cpu` extra (`requirements_from_metadata`), pinned to the x86 environment's versions;
* the model-output worker (`run_models`): each ONNX model on saved inputs, through the
  runtime's own session options (`litevloc.models.ort.make_session`); the same code runs under
  x86 and under the emulated aarch64 Python, inputs and outputs in `.npz` files (no pickle);
* the comparisons: poses of two TUM trajectories (`compare_poses`) and model outputs
  (`compare_outputs`; keypoints are paired by position, so a different top-k choice among
  equal scores is told apart from a wrong value).

Only numpy is imported at module level: the worker imports onnxruntime when it runs.
"""

from __future__ import annotations

import json
import re
import sys
import time
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

# Debian (bookworm) arm64 packages of the sysroot: Python 3.11 and every library its binary, its
# lib-dynload modules and the wheels' `.so` files load (`readelf -d`: the wheels themselves need
# only libc, libm, libstdc++, libgcc_s and zlib; the rest is the standard library's).
SYSROOT_PACKAGES: tuple[str, ...] = (
    "python3.11", "python3.11-minimal", "libpython3.11-minimal", "libpython3.11-stdlib",
    "libc6", "libstdc++6", "libgcc-s1", "zlib1g", "libffi8", "libssl3", "libexpat1", "libbz2-1.0",
    "liblzma5", "libcrypt1", "libuuid1", "libsqlite3-0", "libncursesw6", "libtinfo6", "libreadline8",
    "libdb5.3", "libnsl2", "libtirpc3", "libgssapi-krb5-2", "libkrb5-3", "libk5crypto3", "libkrb5support0",
    "libcom-err2", "libkeyutils1",
)

# pip's platform tags of the wheels: manylinux up to glibc 2.28 (JetPack 5 has glibc 2.31,
# JetPack 6 2.35; the sysroot's Debian 12 has 2.36).
PIP_PLATFORMS: tuple[str, ...] = ("manylinux2014_aarch64", "manylinux_2_17_aarch64", "manylinux_2_28_aarch64")

# One core of a Jetson Orin (Cortex-A78AE: implementer 0x41 Arm, part 0xd42) as its kernel prints it.
_ORIN_CORE = (
    "processor\t: {i}\n"
    "model name\t: ARMv8 Processor rev 1 (v8l)\n"
    "BogoMIPS\t: 62.50\n"
    "Features\t: fp asimd evtstrm aes pmull sha1 sha2 crc32 atomics fphp asimdhp cpuid asimdrdm lrcpc dcpop "
    "asimddp uscat ilrcpc flagm paca pacg\n"
    "CPU implementer\t: 0x41\n"
    "CPU architecture: 8\n"
    "CPU variant\t: 0x0\n"
    "CPU part\t: 0xd42\n"
    "CPU revision\t: 1\n"
    "\n"
)


def cpuinfo_text(n_cpus: int) -> str:
    """An Orin's `/proc/cpuinfo` with `n_cpus` cores (numbered 0..n-1). qemu-user looks paths up
    under its `-L` sysroot first, so `SYSROOT/proc/cpuinfo` is what the emulated process reads;
    the host's `/sys/devices/system/cpu` still says how many CPUs there are, so `n_cpus` is the
    host's count, to agree with it (onnxruntime's cpuinfo probe crashes on the x86 text; other
    counts were not tried)."""
    if n_cpus < 1:
        raise ValueError(f"n_cpus must be >= 1, got {n_cpus}")
    return "".join(_ORIN_CORE.format(i=i) for i in range(n_cpus))


def sysroot_files(n_cpus: int) -> dict[str, str]:
    """Files (path relative to the sysroot -> text) the sysroot holds besides the packages."""
    return {"proc/cpuinfo": cpuinfo_text(n_cpus)}


_NEEDED_RE = re.compile(r"\(NEEDED\)\s+Shared library: \[([^\]]+)\]")


def needed_libraries(readelf_dynamic: str) -> list[str]:
    """The NEEDED entries of `readelf -d FILE` output, in order."""
    return _NEEDED_RE.findall(readelf_dynamic)


def unresolved_libraries(needed: Mapping[str, Sequence[str]], provided: Iterable[str]) -> dict[str, list[str]]:
    """{library: [files needing it]} of the NEEDED libraries no file of the sysroot or of the
    installed wheels provides (`provided`: file names). Wheels carry their own libraries in
    `<package>.libs/` and find them by RPATH; a name match is what the check can see without
    running the loader (the emulated imports are the proof)."""
    have = set(provided)
    out: dict[str, list[str]] = {}
    for file, libs in sorted(needed.items()):
        for lib in libs:
            if lib not in have:
                out.setdefault(lib, []).append(file)
    return out


_REQ_NAME_RE = re.compile(r"^\s*([A-Za-z0-9][A-Za-z0-9._-]*)")
_EXTRA_RE = re.compile(r"""^extra\s*==\s*["']([^"']+)["']$""")


def canonical_name(name: str) -> str:
    """A distribution name as PEP 503 compares them (lower case, runs of -_. as one -)."""
    return re.sub(r"[-_.]+", "-", name).lower()


def requirements_from_metadata(metadata: str, extras: Sequence[str] = ("cpu",)) -> list[str]:
    """The `Requires-Dist` requirements of a wheel's METADATA text that apply without extras or
    with one of `extras` (the extra's marker removed; an extra the wheel lacks adds nothing).
    Other markers stay on the requirement (pip evaluates them). onnxruntime is added when neither
    the base nor the extras name it (it is the check's subject)."""
    out: list[str] = []
    for line in metadata.splitlines():
        if not line.startswith("Requires-Dist:"):
            continue
        req, _, marker = line[len("Requires-Dist:"):].partition(";")
        req, marker = req.strip(), marker.strip()
        if marker:
            m = _EXTRA_RE.match(marker)
            if m:
                if m.group(1) not in extras:
                    continue
                marker = ""
            elif "extra" in marker:
                continue  # a compound marker of some extra: not the runtime's
        out.append(f"{req}; {marker}" if marker else req)
    if not any(canonical_name(requirement_name(r)) == "onnxruntime" for r in out):
        out.append("onnxruntime")
    return list(dict.fromkeys(out))


def requirement_name(req: str) -> str:
    """The distribution name a requirement string starts with."""
    m = _REQ_NAME_RE.match(req)
    if not m:
        raise ValueError(f"not a requirement: {req!r}")
    return m.group(1)


def pinned(requirements: Sequence[str], versions: Mapping[str, str], exclude: Iterable[str] = ()) -> list[str]:
    """`name==version` for every requirement whose distribution has a version in `versions` (the
    x86 environment's, keyed by canonical name), the requirement as given otherwise; the names in
    `exclude` dropped. Both sides then run the same releases."""
    skip = {canonical_name(n) for n in exclude}
    out = []
    for req in requirements:
        name = canonical_name(requirement_name(req))
        if name in skip:
            continue
        out.append(f"{requirement_name(req)}=={versions[name]}" if name in versions else req)
    return out


# --- poses -------------------------------------------------------------------------------------

F64 = NDArray[np.float64]


def parse_tum(text: str) -> dict[float, F64]:
    """{timestamp s: (7,) [tx ty tz qx qy qz qw]} of a TUM trajectory text (# lines skipped)."""
    out: dict[float, F64] = {}
    for line in text.splitlines():
        parts = line.split()
        if not parts or parts[0].startswith("#"):
            continue
        if len(parts) != 8:
            raise ValueError(f"TUM lines have 8 fields, got {len(parts)}: {line!r}")
        out[float(parts[0])] = np.array([float(p) for p in parts[1:]], np.float64)
    return out


def quat_angle_deg(qa: F64, qb: F64) -> float:
    """The rotation angle (degrees) between two unit quaternions (either sign), from the chord
    |qa - qb| = 2 sin(theta / 4): precise near zero, where arccos of the dot product is not."""
    qa, qb = qa / np.linalg.norm(qa), qb / np.linalg.norm(qb)
    chord = min(float(np.linalg.norm(qa - qb)), float(np.linalg.norm(qa + qb)))
    return float(np.degrees(4.0 * np.arcsin(min(1.0, chord / 2.0))))


@dataclass(frozen=True)
class PoseDiff:
    """Two runs' accepted poses compared frame by frame (timestamps to 1 µs)."""

    frames_both: int
    only_reference: int  # frames the reference (x86) run accepted and the other did not
    only_other: int
    max_m: float  # largest position difference over the frames both accepted (metres)
    max_deg: float  # largest rotation difference (degrees, the angle of R_ref^T R_other)
    per_frame: tuple[tuple[float, float, float], ...]  # (t s, m, deg)

    def passed(self, tol_m: float) -> bool:
        """The same frames accepted and every position within `tol_m` metres."""
        return self.frames_both > 0 and self.only_reference == 0 and self.only_other == 0 and self.max_m <= tol_m


def compare_poses(reference: Mapping[float, F64], other: Mapping[float, F64]) -> PoseDiff:
    """Position and rotation differences of the frames both trajectories hold (`parse_tum`)."""
    ref = {round(t, 6): v for t, v in reference.items()}
    oth = {round(t, 6): v for t, v in other.items()}
    both = sorted(set(ref) & set(oth))
    rows = tuple((t, float(np.linalg.norm(ref[t][:3] - oth[t][:3])), quat_angle_deg(ref[t][3:], oth[t][3:]))
                 for t in both)
    return PoseDiff(len(both), len(set(ref) - set(oth)), len(set(oth) - set(ref)),
                    max((r[1] for r in rows), default=float("nan")), max((r[2] for r in rows), default=float("nan")),
                    rows)


# --- model outputs -----------------------------------------------------------------------------


@dataclass(frozen=True)
class Tolerance:
    """What counts as the same output. Floats: |a - b| <= atol + rtol * max|reference| of that
    output (float32 kernels of another instruction set sum in another order: ~1e-6 relative per
    operation; a wrong kernel is off by O(1)). Integer outputs (match indices): at least
    `min_agree` of the entries equal. Keypoints: paired when within `kpt_px` pixels."""

    rtol: float = 1e-3
    atol: float = 1e-5
    min_agree: float = 0.99
    kpt_px: float = 0.01


@dataclass(frozen=True)
class OutputDiff:
    """One output of one model, reference (x86) against the other (aarch64)."""

    model: str
    output: str
    shape: tuple[int, ...]
    max_abs: float  # floats: largest |a - b| (over the paired keypoints for an extractor)
    scale: float  # max |reference| of the output (the rtol's scale)
    agree: float  # share of entries (int outputs) or keypoints (extractor) that agree, 0..1
    note: str
    passed: bool


def _float_diff(model: str, name: str, a: NDArray[Any], b: NDArray[Any], tol: Tolerance, note: str = "",
                agree: float = 1.0) -> OutputDiff:
    a64, b64 = np.asarray(a, np.float64), np.asarray(b, np.float64)
    if a64.shape != b64.shape:
        return OutputDiff(model, name, tuple(a64.shape), float("inf"), 0.0, 0.0,
                          f"shape {a64.shape} vs {b64.shape}", False)
    if a64.size == 0:
        return OutputDiff(model, name, tuple(a64.shape), 0.0, 0.0, agree, note or "empty", agree >= tol.min_agree)
    finite = np.isfinite(a64) == np.isfinite(b64)
    d = np.abs(a64 - b64)
    d[~np.isfinite(a64) & ~np.isfinite(b64) & (a64 == b64)] = 0.0  # the same inf
    max_abs = float(np.max(np.where(finite, np.nan_to_num(d, nan=np.inf), np.inf)))
    scale = float(np.max(np.abs(a64[np.isfinite(a64)]), initial=0.0))
    ok = max_abs <= tol.atol + tol.rtol * scale and agree >= tol.min_agree
    return OutputDiff(model, name, tuple(a64.shape), max_abs, scale, agree, note, ok)


def _int_diff(model: str, name: str, a: NDArray[Any], b: NDArray[Any], tol: Tolerance) -> OutputDiff:
    if a.shape != b.shape:
        return OutputDiff(model, name, tuple(a.shape), float("inf"), 0.0, 0.0, f"shape {a.shape} vs {b.shape}", False)
    agree = float(np.mean(a == b)) if a.size else 1.0
    n_diff = int(np.sum(a != b))
    return OutputDiff(model, name, tuple(a.shape), float(n_diff), 0.0, agree,
                      f"{n_diff} of {a.size} entries differ", agree >= tol.min_agree)


def pair_keypoints(ka: NDArray[Any], kb: NDArray[Any], max_px: float) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """(ia, ib): mutual nearest keypoints of two (N, 2) / (M, 2) sets within `max_px` pixels."""
    a, b = np.asarray(ka, np.float64).reshape(-1, 2), np.asarray(kb, np.float64).reshape(-1, 2)
    if len(a) == 0 or len(b) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    d = np.linalg.norm(a[:, None, :] - b[None, :, :], axis=2)
    nb, na = np.argmin(d, axis=1), np.argmin(d, axis=0)
    ia = np.nonzero((na[nb] == np.arange(len(a))) & (d[np.arange(len(a)), nb] <= max_px))[0]
    return ia.astype(np.int64), nb[ia].astype(np.int64)


def compare_extractor(model: str, ref: Sequence[NDArray[Any]], other: Sequence[NDArray[Any]],
                      tol: Tolerance) -> list[OutputDiff]:
    """ALIKED's (keypoints (K, 2) px, descriptors (K, D), scores (K,)): keypoints paired by position
    (`pair_keypoints`); descriptors and scores compared over the pairs. A keypoint without a
    partner is a top-k tie when its score is within tolerance of the other set's lowest kept
    score (the cut); `agree` is the paired share, and the unpaired ones that are not ties fail."""
    (ka, da, sa), (kb, db, sb) = (tuple(np.asarray(x) for x in ref[:3]), tuple(np.asarray(x) for x in other[:3]))
    ka, kb, sa, sb = ka.reshape(-1, 2), kb.reshape(-1, 2), sa.reshape(-1), sb.reshape(-1)
    da, db = da.reshape(len(ka), -1), db.reshape(len(kb), -1)
    ia, ib = pair_keypoints(ka, kb, tol.kpt_px)
    n = max(len(ka), len(kb), 1)
    agree = len(ia) / n
    s_tol = tol.atol + tol.rtol * float(np.max(np.abs(sa), initial=0.0))
    cut_a, cut_b = float(np.min(sa, initial=np.inf)), float(np.min(sb, initial=np.inf))
    lone_a = np.setdiff1d(np.arange(len(ka)), ia)
    lone_b = np.setdiff1d(np.arange(len(kb)), ib)
    not_ties = int(np.sum(sa[lone_a] > cut_b + s_tol) + np.sum(sb[lone_b] > cut_a + s_tol))
    note = f"{len(ia)}/{len(ka)} keypoints paired within {tol.kpt_px} px"
    if len(lone_a) or len(lone_b):
        note += f"; {len(lone_a)} + {len(lone_b)} unpaired, {not_ties} of them not at the top-k cut"
    # the paired share gates nothing: an unpaired keypoint fails only when it is not a tie
    paired = Tolerance(tol.rtol, tol.atol, 0.0, tol.kpt_px)
    pos = _float_diff(model, "keypoints", ka[ia], kb[ib], Tolerance(0.0, tol.kpt_px, 0.0, tol.kpt_px), note, agree)
    pos = OutputDiff(**{**asdict(pos), "passed": pos.passed and not_ties == 0})
    return [pos, _float_diff(model, "descriptors", da[ia], db[ib], paired, "over the paired keypoints", agree),
            _float_diff(model, "scores", sa[ia], sb[ib], paired, "over the paired keypoints", agree)]


def compare_outputs(model: str, kind: str, names: Sequence[str], ref: Sequence[NDArray[Any]],
                    other: Sequence[NDArray[Any]], tol: Tolerance = Tolerance()) -> list[OutputDiff]:
    """Every output of one model run: `kind` "extractor" pairs keypoints (`compare_extractor`);
    otherwise integer outputs (match indices) by agreement and float ones by max abs difference."""
    if len(ref) != len(other):
        return [OutputDiff(model, "*", (), float("inf"), 0.0, 0.0, f"{len(ref)} vs {len(other)} outputs", False)]
    if kind == "extractor":
        return compare_extractor(model, ref, other, tol)
    out = []
    for name, a, b in zip(names, ref, other, strict=True):
        a, b = np.asarray(a), np.asarray(b)
        if np.issubdtype(a.dtype, np.integer) or a.dtype == np.bool_:
            out.append(_int_diff(model, name, a, b, tol))
        else:
            out.append(_float_diff(model, name, a, b, tol))
    return out


# --- the worker: ONNX models on saved inputs ---------------------------------------------------

INDEX = "index.json"  # in the inputs folder: [{"name", "kind", "onnx", "feeds"}] (feeds: an .npz beside it)


def save_npz(path: Path, arrays: Mapping[str, NDArray[Any]]) -> None:
    """Arrays by name into an uncompressed `.npz` (read back with allow_pickle=False)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    named: dict[str, Any] = {k: np.ascontiguousarray(v) for k, v in arrays.items()}
    np.savez(str(path), allow_pickle=False, **named)


def load_npz(path: Path) -> dict[str, NDArray[Any]]:
    with np.load(str(path), allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def run_models(inputs_dir: Path, out_dir: Path, threads: int = 2, only: Sequence[str] = ()) -> dict[str, float]:
    """Run every model of `inputs_dir/index.json` on its saved feeds with the runtime's session
    options and write its outputs (by output name, in the model's order) to `out_dir/NAME.npz`;
    `out_dir/timings.json`: {name: seconds of session creation + one run}. Progress on stderr."""
    from litevloc.models.ort import make_session

    index = json.loads((inputs_dir / INDEX).read_text())
    if only:
        index = [e for e in index if e["name"] in only]
    timings: dict[str, float] = {}
    out_dir.mkdir(parents=True, exist_ok=True)
    t_all = time.perf_counter()
    for k, entry in enumerate(index, 1):
        t0 = time.perf_counter()
        sess = make_session(Path(entry["onnx"]), ("cpu",), threads)
        feeds = load_npz(inputs_dir / entry["feeds"])
        outs = sess.run(None, feeds)
        names = [o.name for o in sess.get_outputs()]
        save_npz(out_dir / f"{entry['name']}.npz", dict(zip(names, outs, strict=True)))
        (out_dir / f"{entry['name']}.names.json").write_text(json.dumps(names))
        timings[entry["name"]] = time.perf_counter() - t0
        print(f"[models {k}/{len(index)}] {entry['name']}: {timings[entry['name']]:.1f} s "
              f"({time.perf_counter() - t_all:.0f} s so far)", file=sys.stderr, flush=True)
    (out_dir / "timings.json").write_text(json.dumps(timings, indent=1))
    return timings


def read_outputs(out_dir: Path, name: str) -> tuple[list[str], list[NDArray[Any]]]:
    """(output names, arrays in the model's order) that `run_models` wrote for model `name`."""
    names: list[str] = json.loads((out_dir / f"{name}.names.json").read_text())
    arrays = load_npz(out_dir / f"{name}.npz")
    return names, [arrays[n] for n in names]


def main(argv: Sequence[str] | None = None) -> int:
    """`python -m litevloc.experiments.aarch64 run-models INPUTS OUT [--threads N] [--only NAME...]`
    (what the check runs under x86 and under the emulated aarch64 Python)."""
    import argparse

    ap = argparse.ArgumentParser(prog="python -m litevloc.experiments.aarch64")
    sub = ap.add_subparsers(dest="cmd", required=True)
    p = sub.add_parser("run-models", help="run the models of INPUTS/index.json, outputs to OUT")
    p.add_argument("inputs", type=Path)
    p.add_argument("out", type=Path)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--only", nargs="*", default=[])
    args = ap.parse_args(argv)
    run_models(args.inputs, args.out, args.threads, args.only)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
