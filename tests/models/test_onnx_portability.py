"""The exported models load and agree on every onnxruntime a user may have, and parse in TensorRT.

onnxruntime: `make install-dev` installs the older CPU builds named in the Makefile
(ONNXRUNTIME_COMPAT: 1.20 to 1.23, the Jetson GPU wheel's 1.23 among them) beside the venv's
newest, under `<venv>/ort/<version>`. Every model the runtime uses (the adaptive LightGlue part by
part) runs on the same 7-Scenes inputs under each build in its own process
(`python -m litevloc.experiments.model_conformance run-models`, as the aarch64 check runs it
under qemu) and must give the newest's outputs within `model_conformance.Tolerance`.

TensorRT: no GPU here, so no parser runs. What is checked is the operator list of each model
against the operators that onnx-tensorrt 10.1's docs/operators.md marks supported (TensorRT 10.x,
JetPack 6 ships 10.3), the opset range it states (9 to 20) and the restrictions there that our
operators have (TopK's K < 3840, ScatterND without `reduction`, GridSample on 4-D inputs). The
optional int8 LightGlue (`lightglue-int8`, onnxruntime's dynamic quantization for CPUs) is the
exception: its DynamicQuantizeLinear and MatMulInteger nodes run on onnxruntime's CPU or CUDA
provider, the rest on TensorRT; on a GPU the fp32 models with `models.tensorrt.fp16` are the choice.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from litevloc.experiments import model_conformance as mc

onnx = pytest.importorskip("onnx")

# onnx-tensorrt 10.1 (2024-06), docs/operators.md: every operator marked "Y"
TENSORRT_ONNX_OPS = frozenset((
    "Abs", "Acos", "Acosh", "Add", "And", "ArgMax", "ArgMin", "Asin", "Asinh", "Atan", "Atanh", "AveragePool",
    "BatchNormalization", "Cast", "CastLike", "Ceil", "Celu", "Clip", "Concat", "Constant", "ConstantOfShape",
    "Conv", "ConvTranspose", "Cos", "Cosh", "CumSum", "DeformConv", "DepthToSpace", "DequantizeLinear", "Div",
    "Dropout", "Einsum", "Elu", "Equal", "Erf", "Exp", "Expand", "EyeLike", "Flatten", "Floor", "Gather",
    "GatherElements", "GatherND", "Gelu", "Gemm", "GlobalAveragePool", "GlobalLpPool", "GlobalMaxPool", "Greater",
    "GreaterOrEqual", "GridSample", "GroupNormalization", "GRU", "HardSigmoid", "HardSwish", "Hardmax",
    "Identity", "If", "ImageScaler", "InstanceNormalization", "IsInf", "IsNaN", "LayerNormalization", "LeakyRelu",
    "Less", "LessOrEqual", "Log", "LogSoftmax", "Loop", "LRN", "LSTM", "LpNormalization", "LpPool", "MatMul",
    "Max", "MaxPool", "Mean", "MeanVarianceNormalization", "Min", "Mish", "Mod", "Mul", "Neg",
    "NonMaxSuppression", "NonZero", "Not", "OneHot", "Or", "Pad", "ParametricSoftplus", "Pow", "PRelu",
    "QuantizeLinear", "RandomNormal", "RandomNormalLike", "RandomUniform", "RandomUniformLike", "Range",
    "Reciprocal", "ReduceL1", "ReduceL2", "ReduceLogSum", "ReduceLogSumExp", "ReduceMax", "ReduceMean",
    "ReduceMin", "ReduceProd", "ReduceSum", "ReduceSumSquare", "Relu", "Reshape", "Resize", "ReverseSequence",
    "RNN", "RoiAlign", "Round", "ScaledTanh", "Scan", "Scatter", "ScatterElements", "ScatterND", "Selu", "Shape",
    "Shrink", "Sigmoid", "Sign", "Sin", "Sinh", "Size", "Slice", "Softmax", "Softplus", "Softsign",
    "SpaceToDepth", "Split", "Sqrt", "Squeeze", "Sub", "Sum", "Tan", "Tanh", "ThresholdedRelu", "Tile", "TopK",
    "Transpose", "Trilu", "Unsqueeze", "Upsample", "Where", "Xor"
))
TENSORRT_OPSETS = range(9, 21)


def _onnx_files(cache: Path) -> list[Path]:
    files = sorted(cache.glob("*.onnx"))
    assert files, f"no ONNX models in {cache}"
    return files


DYNAMIC_INT8_OPS = frozenset(("DynamicQuantizeLinear", "MatMulInteger"))


def test_every_model_uses_only_operators_tensorrt_parses(model_cache: Path) -> None:
    from litevloc.models.registry import read_manifest

    quantized = {f for e in read_manifest(model_cache)["models"].values() if e.get("quantization")
                 for f in [e["file"], *(e.get("parts_sha256") or {})]}
    for path in _onnx_files(model_cache):
        proto = onnx.load(str(path))
        opset = next(o.version for o in proto.opset_import if o.domain in ("", "ai.onnx"))
        assert opset in TENSORRT_OPSETS, f"{path.name}: opset {opset}"
        ops = {n.op_type for n in proto.graph.node}
        allowed = TENSORRT_ONNX_OPS | (DYNAMIC_INT8_OPS if path.name in quantized else frozenset())
        assert ops <= allowed, f"{path.name}: {sorted(ops - allowed)} not in TensorRT's parser"
        assert "DeformConv" not in ops, f"{path.name}: DeformConv has no kernel in onnxruntime < 1.25"
        consts = {i.name: onnx.numpy_helper.to_array(i) for i in proto.graph.initializer}
        for node in proto.graph.node:
            if node.op_type == "Constant":
                consts[node.output[0]] = onnx.numpy_helper.to_array(node.attribute[0].t)
        for node in proto.graph.node:
            if node.op_type == "TopK" and node.input[1] in consts:
                assert int(np.asarray(consts[node.input[1]]).max()) < 3840, f"{path.name}: TopK K >= 3840"
            if node.op_type == "ScatterND":
                assert not any(a.name == "reduction" for a in node.attribute), f"{path.name}: ScatterND reduction"


@pytest.mark.shared_data
def test_older_onnxruntime_builds_give_the_newest_outputs(model_cache: Path, seven_scenes_dir: Path,
                                                          tmp_path: Path) -> None:
    builds = sorted((Path(sys.prefix) / "ort").glob("1.*"))
    versions = {p.name.rsplit(".", 1)[0] for p in builds}
    assert {"1.20", "1.23"} <= versions, (
        f"older onnxruntime builds missing under {Path(sys.prefix) / 'ort'} (have {sorted(versions)}): "
        "`make install-dev` installs them")
    index = mc.prepare_model_inputs(seven_scenes_dir, tmp_path / "inputs")
    assert len(index) >= 20  # 3 extractors, LightGlue, the adaptive one's 19 parts, VPR
    mc.run_models(tmp_path / "inputs", tmp_path / "newest", threads=1)
    for build in builds:
        out = tmp_path / build.name
        proc = subprocess.run(
            [sys.executable, "-m", "litevloc.experiments.model_conformance", "run-models", str(tmp_path / "inputs"),
             str(out), "--threads", "1"],
            env={**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, (str(build), os.environ.get("PYTHONPATH"))))},
            capture_output=True, text=True, timeout=300)
        assert proc.returncode == 0, proc.stderr[-2000:]
        assert json.loads((out / "runtime.json").read_text())["onnxruntime"] == build.name
        failed = [d for d in mc.compare_models(index, tmp_path / "newest", out) if not d.passed]
        assert not failed, f"onnxruntime {build.name}: {failed}"
