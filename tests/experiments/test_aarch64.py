"""The aarch64 check's pure parts (no qemu): the sysroot plan, the requirements it installs, and the
comparison of poses that decides whether the emulated run agrees with x86 (model outputs:
test_model_conformance.py)."""

from __future__ import annotations

import numpy as np
import pytest

from litevloc.experiments import aarch64 as a64

READELF = """
Dynamic section at offset 0x1f0 contains 30 entries:
  Tag        Type                         Name/Value
 0x0000000000000001 (NEEDED)             Shared library: [libstdc++.so.6]
 0x0000000000000001 (NEEDED)             Shared library: [libgomp-a34b3233.so.1.0.0]
 0x000000000000000e (SONAME)             Library soname: [libfoo.so]
 0x000000000000000f (RPATH)              Library rpath: [$ORIGIN/../foo.libs]
 0x0000000000000001 (NEEDED)             Shared library: [libc.so.6]
"""

METADATA = """Metadata-Version: 2.1
Name: litevloc
Requires-Python: >=3.10
Requires-Dist: numpy>=1.26
Requires-Dist: opencv-python-headless>=4.9
Requires-Dist: tomli>=2; python_version < "3.11"
Provides-Extra: cpu
Requires-Dist: onnxruntime>=1.18; extra == "cpu"
Provides-Extra: gpu
Requires-Dist: onnxruntime-gpu>=1.18; extra == "gpu"
Provides-Extra: dev
Requires-Dist: pytest>=8; extra == 'dev'
Requires-Dist: rerun-sdk<0.42,>=0.41; python_version >= "3.10" and extra == "view"
"""


def test_cpuinfo_is_an_orin_with_the_hosts_core_count() -> None:
    text = a64.cpuinfo_text(3)
    blocks = [b for b in text.split("\n\n") if b.strip()]
    assert [b.splitlines()[0] for b in blocks] == ["processor\t: 0", "processor\t: 1", "processor\t: 2"]
    for b in blocks:  # Arm's Cortex-A78AE, as onnxruntime's cpuinfo probe parses it
        assert "CPU implementer\t: 0x41" in b and "CPU part\t: 0xd42" in b and "CPU architecture: 8" in b
        assert " asimd " in b and "asimddp" in b
    assert a64.sysroot_files(2) == {"proc/cpuinfo": a64.cpuinfo_text(2)}
    with pytest.raises(ValueError):
        a64.cpuinfo_text(0)


def test_the_sysroot_holds_python_and_the_libraries_the_wheels_load() -> None:
    for pkg in ("python3.11", "libpython3.11-stdlib", "libc6", "libstdc++6", "libgcc-s1", "zlib1g"):
        assert pkg in a64.SYSROOT_PACKAGES
    assert all(p.endswith("_aarch64") for p in a64.PIP_PLATFORMS)


def test_needed_libraries_and_the_unresolved_ones() -> None:
    libs = a64.needed_libraries(READELF)
    assert libs == ["libstdc++.so.6", "libgomp-a34b3233.so.1.0.0", "libc.so.6"]
    provided = ["libc.so.6", "libstdc++.so.6", "libz.so.1"]
    missing = a64.unresolved_libraries({"b.so": libs, "a.so": ["libz.so.1", "libgomp-a34b3233.so.1.0.0"]}, provided)
    assert missing == {"libgomp-a34b3233.so.1.0.0": ["a.so", "b.so"]}
    assert a64.unresolved_libraries({"a.so": libs}, [*provided, "libgomp-a34b3233.so.1.0.0"]) == {}


def test_requirements_are_the_runtimes_plus_the_cpu_extra_pinned_to_the_host() -> None:
    reqs = a64.requirements_from_metadata(METADATA)
    assert reqs == ["numpy>=1.26", "opencv-python-headless>=4.9", 'tomli>=2; python_version < "3.11"',
                    "onnxruntime>=1.18"]
    # before onnxruntime moved to an extra: it is a base requirement, and is not added twice
    old = "Requires-Dist: numpy>=1.26\nRequires-Dist: onnxruntime>=1.18\nRequires-Dist: dev-tool; extra == 'dev'\n"
    assert a64.requirements_from_metadata(old) == ["numpy>=1.26", "onnxruntime>=1.18"]
    assert a64.requirements_from_metadata("Requires-Dist: numpy\n") == ["numpy", "onnxruntime"]
    pins = a64.pinned(reqs, {"numpy": "2.4.6", "opencv-python-headless": "5.0.0.93", "onnxruntime": "1.32.0"},
                      exclude=["Tomli"])
    assert pins == ["numpy==2.4.6", "opencv-python-headless==5.0.0.93", "onnxruntime==1.32.0"]
    branches = ["gtsam>=4.2; python_version >= '3.11'", "gtsam==4.3a1; python_version < '3.11'"]
    assert a64.pinned(branches, {"gtsam": "4.3.0"}) == ["gtsam==4.3.0"]  # the installed one, once
    assert a64.canonical_name("Opencv_Python.Headless") == "opencv-python-headless"


def _tum(rows: list[tuple[float, list[float]]]) -> str:
    return "# t tx ty tz qx qy qz qw\n" + "\n".join(f"{t:.9f} " + " ".join(f"{v:.9f}" for v in p) for t, p in rows)


def _q(deg: float) -> list[float]:  # a rotation about z, xyzw
    h = np.radians(deg) / 2
    return [0.0, 0.0, float(np.sin(h)), float(np.cos(h))]


def test_pose_differences_in_position_and_rotation() -> None:
    ref = a64.parse_tum(_tum([(1.0, [1, 2, 3, *_q(10)]), (2.0, [0, 0, 0, *_q(0)])]))
    same = a64.compare_poses(ref, ref)
    assert same.frames_both == 2 and same.max_m == 0.0 and same.max_deg < 1e-6 and same.passed(0.01)
    moved = a64.parse_tum(_tum([(1.0, [1, 2.02, 3, *_q(10.5)]), (2.0, [0, 0, 0.001, *[-v for v in _q(0)]])]))
    d = a64.compare_poses(ref, moved)
    assert d.max_m == pytest.approx(0.02, abs=1e-9) and d.max_deg == pytest.approx(0.5, abs=1e-6)
    assert d.per_frame[1][1] == pytest.approx(0.001) and d.per_frame[1][2] < 1e-6  # q and -q: the same rotation
    assert not d.passed(0.01) and d.passed(0.03)
    fewer = a64.compare_poses(ref, {1.0: ref[1.0]})  # a frame only x86 accepted fails the check
    assert fewer.only_reference == 1 and not fewer.passed(1.0)
    assert a64.quat_angle_deg(np.array(_q(0.0)), np.array(_q(1e-4))) == pytest.approx(1e-4, rel=1e-3)
    with pytest.raises(ValueError):
        a64.parse_tum("1.0 2.0 3.0\n")


def test_the_figures_row_reads_the_checks_json(tmp_path) -> None:  # type: ignore[no-untyped-def]
    import json

    from litevloc.experiments.report import HEADLINES, row_from_json

    h = next(h for h in HEADLINES if h.json == "bench/aarch64.json")
    counts = {"queries": 3, "accepted": 3, "global": 1, "local": 2}
    d = {"meta": {"time": "2026-12-02T05:00:00+0000", "cpu": "Xeon", "cpus": 2, "load_avg": 3.0}, "wall_s": 600.0,
         "localize": {"frames_both": 3, "max_m": 1.7e-8, "max_deg": 3.9e-7, "passed": True,
                      "counts": {"x86": counts, "aarch64": counts}},
         "models": {"count": 24, "passed": False, "worst_relative": 7e-5}}
    (tmp_path / "a.json").write_text(json.dumps(d))
    row = row_from_json(h, tmp_path / "a.json")
    assert row[0] == h.what and row[2] == "2026-12-02" and row[4] == "`make aarch64-check`"
    assert "3 of 3" in row[1] and "2e-06 cm" in row[1] and "NOT within" in row[1] and "10 min" in row[1]


def test_without_qemu_or_apt_the_check_stops_with_one_line(tmp_path, monkeypatch, capsys) -> None:  # type: ignore[no-untyped-def]
    import importlib.util
    import shutil
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    spec = importlib.util.spec_from_file_location("aarch64_check", root / "tools" / "aarch64_check.py")
    assert spec is not None and spec.loader is not None
    tool = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tool)
    (tmp_path / "frame-000000.color.jpg").write_bytes(b"")
    monkeypatch.setattr(shutil, "which", lambda _name: None)  # neither qemu-aarch64-static nor apt-get
    assert tool.main(["--data", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("aarch64 check: apt-get is not available")
    assert tool.main(["--data", str(tmp_path / "nowhere")]) == 2
    assert "needs the 7-Scenes data" in capsys.readouterr().err
