"""`litevloc info`: versions, execution providers, presets, caches, data found."""

from __future__ import annotations

import argparse
import importlib.metadata as md
import platform
from pathlib import Path

from litevloc.cli.common import add_json_arg
from litevloc.config import preset_names
from litevloc.runtime.tools.outputs import write_json

_PACKAGES = ("numpy", "opencv-python-headless", "onnxruntime", "onnxruntime-gpu", "gtsam", "eclipse-zenoh", "pyyaml",
             "depthai", "mcap", "rosbags")


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("info", help="show versions, ONNX Runtime providers, presets and caches")
    add_json_arg(p)
    p.set_defaults(func=run)


def _version(name: str) -> str:
    try:
        return md.version(name)
    except md.PackageNotFoundError:
        return "not installed"


def _onnxruntime() -> tuple[str, list[str]]:
    """The imported onnxruntime's build in words and its providers, or why there is none (`info` must
    not fail where the runtime cannot start)."""
    from litevloc.models.types import OnnxRuntimeMissing

    try:
        from litevloc.models.ort import ort_build
    except OnnxRuntimeMissing as exc:
        return str(exc), []
    b = ort_build()
    clash = f"; WARNING: {' and '.join(b.installed)} installed together" if len(b.installed) > 1 else ""
    return f"{b.distribution} {b.version}, device {b.device}{clash}", list(b.available)


def run(args: argparse.Namespace) -> int:
    onnxruntime, providers = _onnxruntime()
    info: dict = {
        "litevloc": _version("litevloc"),
        "python": platform.python_version(),
        "machine": platform.machine(),
        "packages": {n: _version(n) for n in _PACKAGES},
        "onnxruntime": onnxruntime,
        "onnxruntime_providers": providers,
        "presets": preset_names(),
    }
    try:
        from litevloc.models.registry import default_cache_dir

        info["model_cache"] = str(default_cache_dir())
    except ImportError:
        pass
    shared = Path("../shared/data/7scenes-redkitchen")
    info["shared_7scenes"] = str(shared.resolve()) if shared.is_dir() else None
    width = max(len(k) for k in info)
    for k, v in info.items():
        if isinstance(v, dict):
            print(f"{k:<{width}} : " + ", ".join(f"{a} {b}" for a, b in v.items()))
        else:
            print(f"{k:<{width}} : {v}")
    write_json(args.json, info)
    return 0
