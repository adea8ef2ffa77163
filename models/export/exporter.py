"""Build ONNX models into the cache and keep its manifest (the only place that runs torch.onnx).

`export_models(ids, cache)` is idempotent: a model whose manifest entry matches this code's
EXPORT_VERSION / opset / spec, whose ONNX file has the recorded sha256 and whose source weights
still have the recorded sha256 is skipped ("up-to-date").
"""

from __future__ import annotations

import datetime as _dt
import importlib.util
import logging
import tempfile
import warnings
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import onnx
import torch

from litevloc.models.catalog import EXPORT_VERSION, OPSET, SOURCES, ModelSpec, manifest_fields, spec_for
from litevloc.models.registry import ModelError, read_manifest, sha256_file, write_manifest

log = logging.getLogger(__name__)
ONNX_IR_VERSION = 10  # onnxruntime 1.31 refuses newer IR versions


def package_file(package: str, rel: str) -> Path:
    """A file inside an installed package, found without importing it (find_spec only)."""
    spec = importlib.util.find_spec(package)
    if spec is None or not spec.submodule_search_locations:
        raise ModelError(
            f"package {package!r} is not installed; it ships the weights "
            f"(`make install-dev` installs it with --no-deps)"
        )
    path = Path(next(iter(spec.submodule_search_locations))) / rel
    if not path.is_file():
        raise ModelError(f"{path} is missing from the installed package {package!r}")
    return path


def source_of(spec: ModelSpec, cosplace_checkpoint: Path | None) -> tuple[str, Path]:
    """(package or 'user', path) of the weights `spec` is exported from."""
    if spec.arch == "cosplace-r18":
        if cosplace_checkpoint is None:
            raise ModelError(
                f"{spec.id} needs an official CosPlace ResNet-18 checkpoint: "
                f"`litevloc models export --model {spec.id} --cosplace-checkpoint PATH`"
            )
        if not Path(cosplace_checkpoint).is_file():
            raise ModelError(f"CosPlace checkpoint not found: {cosplace_checkpoint}")
        return "user", Path(cosplace_checkpoint)
    package, rel = SOURCES[spec.arch]
    return package, package_file(package, rel)


def build_torch(spec: ModelSpec, weights: Path) -> torch.nn.Module:
    """The eval-mode torch module for `spec` with `weights` loaded (strict)."""
    if spec.kind == "extractor":
        from litevloc.models.export.aliked import load_aliked

        assert spec.top_k is not None
        return load_aliked(weights, spec.arch, spec.top_k)
    if spec.kind == "matcher":
        from litevloc.models.export.lightglue import load_lightglue

        return load_lightglue(weights)
    from litevloc.models.export.vpr import load_cosplace, load_effnet_gem

    return load_cosplace(weights) if spec.arch == "cosplace-r18" else load_effnet_gem(weights)


def export_onnx(spec: ModelSpec, model: torch.nn.Module, out: Path) -> None:
    """torch -> ONNX (TorchScript exporter, opset 19, IR 10). Fixed image sizes; LightGlue
    has dynamic keypoint counts."""
    out.parent.mkdir(parents=True, exist_ok=True)
    with torch.no_grad():
        if spec.kind == "matcher":
            args: tuple[torch.Tensor, ...] = (
                torch.rand(1, 64, 2) * 2 - 1,
                torch.rand(1, 80, 2) * 2 - 1,
                torch.nn.functional.normalize(torch.randn(1, 64, 128), dim=-1),
                torch.nn.functional.normalize(torch.randn(1, 80, 128), dim=-1),
            )
            names_in = ["kpts0", "kpts1", "desc0", "desc1"]
            names_out = ["matches0", "mscores0"]
            dyn: dict[str, dict[int, str]] | None = {
                "kpts0": {1: "M"},
                "kpts1": {1: "N"},
                "desc0": {1: "M"},
                "desc1": {1: "N"},
                "matches0": {1: "M"},
                "mscores0": {1: "M"},
            }
        else:
            assert spec.input_hw is not None
            args = (torch.rand(1, 3, *spec.input_hw),)
            names_in = ["image"]
            names_out = (
                ["keypoints", "descriptors", "scores"]
                if spec.kind == "extractor"
                else ["descriptor"]
            )
            dyn = None
        with tempfile.TemporaryDirectory() as td, warnings.catch_warnings():
            # shapes are fixed on purpose (tracer warnings about Python ints are expected)
            warnings.simplefilter("ignore")
            tmp = Path(td) / "model.onnx"
            torch.onnx.export(
                model,
                args,
                str(tmp),
                input_names=names_in,
                output_names=names_out,
                dynamic_axes=dyn,
                opset_version=OPSET,
                dynamo=False,
                do_constant_folding=True,
            )
            proto = onnx.load(str(tmp))
    proto.ir_version = ONNX_IR_VERSION
    proto.doc_string = f"litevloc {spec.id} (export version {EXPORT_VERSION})"
    onnx.checker.check_model(proto)
    tmp_out = out.with_suffix(".onnx.tmp")
    onnx.save(proto, str(tmp_out))
    if spec.quantization == "dynamic-int8":
        _quantize_dynamic_int8(tmp_out)
    tmp_out.replace(out)


def _save_checked(proto: onnx.ModelProto, doc: str, out: Path) -> None:
    proto.ir_version = ONNX_IR_VERSION
    proto.doc_string = doc
    onnx.checker.check_model(proto)
    tmp_out = out.with_suffix(".onnx.tmp")
    onnx.save(proto, str(tmp_out))
    tmp_out.replace(out)


def export_adaptive_lightglue(spec: ModelSpec, model: torch.nn.Module, cache: Path) -> None:
    """The parts of adaptive LightGlue (encoder, layer{i}, head{i}), each with dynamic M, N."""
    from litevloc.models.export.lightglue import EncoderPart, HeadPart, LayerPart, LightGlue

    assert isinstance(model, LightGlue)
    cache.mkdir(parents=True, exist_ok=True)
    m, n = 64, 80
    kpts = (torch.rand(1, m, 2) * 2 - 1, torch.rand(1, n, 2) * 2 - 1)
    desc = (torch.nn.functional.normalize(torch.randn(1, m, 128), dim=-1),
            torch.nn.functional.normalize(torch.randn(1, n, 128), dim=-1))
    with torch.no_grad():
        d0, d1, e0, e1 = EncoderPart(model)(*kpts, *desc)
    dyn_d = {"d0": {1: "M"}, "d1": {1: "N"}, "e0": {3: "M"}, "e1": {3: "N"},
             "d0_out": {1: "M"}, "d1_out": {1: "N"}}
    Job = tuple[str, torch.nn.Module, tuple[torch.Tensor, ...], list[str], list[str], dict[str, dict[int, str]]]
    jobs: list[Job] = [
        ("encoder", EncoderPart(model), (*kpts, *desc), ["kpts0", "kpts1", "desc0", "desc1"],
         ["d0", "d1", "e0", "e1"],
         {"kpts0": {1: "M"}, "kpts1": {1: "N"}, "desc0": {1: "M"}, "desc1": {1: "N"}, **dyn_d}),
    ]
    n_layers = len(model.transformers)
    for i in range(n_layers):
        # (an output may not share an input's name: the exporter would rename the input)
        outs = ["d0_out", "d1_out"]
        outs += [] if i == n_layers - 1 else ["conf0", "conf1", "match0", "match1"]
        dyn = {**dyn_d, "conf0": {1: "M"}, "conf1": {1: "N"}, "match0": {1: "M"}, "match1": {1: "N"}}
        jobs.append((f"layer{i}", LayerPart(model, i), (d0, d1, e0, e1), ["d0", "d1", "e0", "e1"], outs,
                     {k: v for k, v in dyn.items() if k in outs or k in ("d0", "d1", "e0", "e1")}))
        jobs.append((f"head{i}", HeadPart(model, i), (d0, d1), ["d0", "d1"], ["matches0", "mscores0"],
                     {"d0": {1: "M"}, "d1": {1: "N"}, "matches0": {1: "M"}, "mscores0": {1: "M"}}))
    files = spec.parts
    for name, part, args, names_in, names_out, dyn in jobs:
        with tempfile.TemporaryDirectory() as td, warnings.catch_warnings(), torch.no_grad():
            warnings.simplefilter("ignore")
            tmp = Path(td) / "part.onnx"
            torch.onnx.export(part, args, str(tmp), input_names=names_in, output_names=names_out,
                              dynamic_axes=dyn, opset_version=OPSET, dynamo=False, do_constant_folding=True)
            proto = onnx.load(str(tmp))
        _save_checked(proto, f"litevloc {spec.id} part {name} (export version {EXPORT_VERSION})", cache / files[name])


def _quantize_dynamic_int8(path: Path) -> None:
    """In place: MatMul/Gemm weights to int8 (per tensor); activations quantised at run time."""
    from onnxruntime.quantization import QuantType, quantize_dynamic

    fp32 = path.with_suffix(".fp32.tmp")
    path.replace(fp32)
    with warnings.catch_warnings(), _quiet_root_logger():
        warnings.simplefilter("ignore")
        quantize_dynamic(
            str(fp32),
            str(path),
            weight_type=QuantType.QInt8,
            op_types_to_quantize=["MatMul", "Gemm"],
        )
    fp32.unlink()
    q = onnx.load(str(path))
    q.ir_version = ONNX_IR_VERSION
    onnx.save(q, str(path))


class _quiet_root_logger:
    """onnxruntime.quantization logs a pre-processing hint on the root logger; silence it."""

    def __enter__(self) -> None:
        self._level = logging.getLogger().level
        logging.getLogger().setLevel(logging.ERROR)

    def __exit__(self, *exc: object) -> None:
        logging.getLogger().setLevel(self._level)


def is_up_to_date(
    entry: dict[str, Any] | None, spec: ModelSpec, path: Path, source_sha: str
) -> bool:
    if entry is None or not path.is_file():
        return False
    if any(entry.get(k) != v for k, v in manifest_fields(spec).items()):
        return False
    if entry.get("source", {}).get("sha256") != source_sha:
        return False
    if spec.adaptive:
        shas = entry.get("parts_sha256") or {}
        return all(
            (path.parent / f).is_file() and sha256_file(path.parent / f) == shas.get(f) for f in spec.part_files
        )
    return bool(sha256_file(path) == entry.get("onnx_sha256"))


def export_models(
    ids: Iterable[str],
    cache: Path,
    force: bool = False,
    cosplace_checkpoint: Path | None = None,
    on_progress: Callable[[str, str], None] | None = None,
) -> dict[str, str]:
    """Export each model id into `cache`; returns {id: "built" | "up-to-date"}.

    on_progress(id, status) is called before ("exporting") and after each model.
    """
    results: dict[str, str] = {}
    torch.set_num_threads(max(1, min(2, torch.get_num_threads())))
    for model_id in ids:
        spec = spec_for(model_id)
        package, src = source_of(spec, cosplace_checkpoint)
        src_sha = sha256_file(src)
        path = cache / spec.filename
        manifest = read_manifest(cache)
        if not force and is_up_to_date(manifest["models"].get(model_id), spec, path, src_sha):
            results[model_id] = "up-to-date"
            if on_progress:
                on_progress(model_id, "up-to-date")
            continue
        if on_progress:
            on_progress(model_id, "exporting")
        model = build_torch(spec, src)
        if spec.adaptive:
            export_adaptive_lightglue(spec, model, cache)
        else:
            export_onnx(spec, model, path)
        manifest = read_manifest(cache)
        manifest["models"][model_id] = {
            "file": spec.filename,
            "onnx_sha256": sha256_file(path),
            **({"parts_sha256": {f: sha256_file(cache / f) for f in spec.part_files}} if spec.adaptive else {}),
            "kind": spec.kind,
            "arch": spec.arch,
            "input_hw": list(spec.input_hw) if spec.input_hw else None,
            "top_k": spec.top_k,
            "quantization": spec.quantization,
            "opset": OPSET,
            "ir_version": ONNX_IR_VERSION,
            "export_version": EXPORT_VERSION,
            "source": {"package": package, "path": str(src), "sha256": src_sha},
            "torch": torch.__version__,
            "created_utc": _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
        }
        write_manifest(cache, manifest)
        results[model_id] = "built"
        if on_progress:
            on_progress(model_id, "built")
    return results
