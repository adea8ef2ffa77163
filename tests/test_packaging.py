"""What `pip install litevloc` asks for on each platform it supports (the installed metadata).

The environment markers are evaluated here for each target, as pip on that target would: on
Python 3.10 (JetPack 6) gtsam is the exact pre-release pin 4.3a1 (no stable cp310 aarch64 wheel
exists), everywhere else a requirement that admits no pre-release; onnxruntime is only ever an
extra, so installing LiteVLoc never replaces a Jetson's GPU build. `python bench/wheels.py`
resolves the same for real, from the registry.
"""

from __future__ import annotations

from importlib import metadata

import pytest
from packaging.requirements import Requirement

TARGETS = [(py, machine) for py in ("3.10", "3.11", "3.12") for machine in ("aarch64", "x86_64")]
ONNXRUNTIMES = {"onnxruntime", "onnxruntime-gpu"}


def _requirements() -> list[Requirement]:
    reqs = metadata.requires("litevloc")
    assert reqs, "litevloc's metadata lists no requirements: is it installed (make install)?"
    return [Requirement(r) for r in reqs]


def _applies(req: Requirement, python: str, machine: str, extra: str = "") -> bool:
    env = {"python_version": python, "python_full_version": f"{python}.0", "platform_machine": machine,
           "sys_platform": "linux", "platform_system": "Linux", "implementation_name": "cpython", "extra": extra}
    return req.marker is None or req.marker.evaluate(env)


def test_python_310_to_312_are_supported() -> None:
    spec = metadata.metadata("litevloc")["Requires-Python"]
    from packaging.specifiers import SpecifierSet

    assert all(v in SpecifierSet(spec) for v in ("3.10.0", "3.11.0", "3.12.0")), spec


@pytest.mark.parametrize(("python", "machine"), TARGETS)
def test_gtsam_is_one_requirement_and_a_pre_release_only_where_pinned_by_name(python: str, machine: str) -> None:
    gtsam = [r for r in _requirements() if r.name == "gtsam" and _applies(r, python, machine)]
    assert len(gtsam) == 1, f"{python} {machine}: {[str(r) for r in gtsam]}"
    spec = gtsam[0].specifier
    if python == "3.10":
        assert str(spec) == "==4.3a1", "Python 3.10 needs the exact pin: cp310 aarch64 has no stable gtsam"
    else:
        assert not spec.prereleases, f"{spec} would admit a gtsam pre-release on {python}"
        assert spec.contains("4.3.0"), f"{spec} refuses the gtsam the suite runs on"


@pytest.mark.parametrize(("python", "machine"), TARGETS)
def test_onnxruntime_comes_only_from_the_cpu_or_gpu_extra(python: str, machine: str) -> None:
    reqs = _requirements()
    base = {r.name for r in reqs if _applies(r, python, machine)}
    assert not base & ONNXRUNTIMES, f"a base dependency on {base & ONNXRUNTIMES} would replace a GPU build"
    for extra, dist in (("cpu", "onnxruntime"), ("gpu", "onnxruntime-gpu")):
        added = {r.name for r in reqs if _applies(r, python, machine, extra)} - base
        assert added & ONNXRUNTIMES == {dist}, f"[{extra}] adds {added & ONNXRUNTIMES}"


def test_the_robot_needs_no_torch_viewer_or_test_tools() -> None:
    base = {r.name for r in _requirements() if _applies(r, "3.10", "aarch64")}
    assert not base & {"torch", "onnx", "rerun-sdk", "pytest", "mypy", "ruff"}, base
