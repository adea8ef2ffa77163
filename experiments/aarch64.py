"""The aarch64 check's own logic (`tools/aarch64_check.py` drives it).

The check runs the runtime's aarch64 wheels on an x86 machine under qemu user-mode emulation
(an arm64 Python from Debian's packages in a sysroot folder) and compares what they compute with
the x86 run of the same code on the same inputs. This module holds the parts without qemu:

* the sysroot plan: the Debian arm64 packages (`SYSROOT_PACKAGES`), the ARM `/proc/cpuinfo` the
  sysroot must hold (`cpuinfo_text`: onnxruntime's CPU probe crashes under qemu-user on the
  host's x86 text), and which shared libraries the wheels' `.so` files need that nothing
  provides (`needed_libraries`, `unresolved_libraries`);
* the wheels to install: the runtime requirements read from the project wheel's metadata plus
  its `cpu` extra (`requirements_from_metadata`), pinned to the x86 environment's versions;
* the comparison of poses of two TUM trajectories (`compare_poses`).

The models' outputs are compared by `litevloc.experiments.model_conformance` (its worker runs
unchanged under x86 and under the emulated aarch64 Python).
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

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
    x86 environment's, keyed by canonical name), the requirement as given otherwise, each once; the
    names in `exclude` dropped. Both sides then run the same releases."""
    skip = {canonical_name(n) for n in exclude}
    out = []
    for req in requirements:
        name = canonical_name(requirement_name(req))
        if name in skip:
            continue
        out.append(f"{requirement_name(req)}=={versions[name]}" if name in versions else req)
    return list(dict.fromkeys(out))  # gtsam's two marker branches pin to the one version installed


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
