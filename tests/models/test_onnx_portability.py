"""The exported models load and agree on every onnxruntime a user may have, and parse in TensorRT.

onnxruntime: `make install-dev` installs the older CPU builds named in the Makefile
(ONNXRUNTIME_COMPAT: 1.20 to 1.23, the Jetson GPU wheel's 1.23 among them) beside the venv's
newest, under `<venv>/ort/<version>`; each runs `python -m litevloc.models.conformance` on two
7-Scenes frames in its own process and must give the newest's outputs within
`conformance.Tolerance`'s defaults.

TensorRT: no GPU here, so no parser runs. What is checked is the operator list of each model
against the operators that onnx-tensorrt 10.1's docs/operators.md marks supported (TensorRT 10.x,
JetPack 6 ships 10.3), the opset range it states (9 to 20) and the restrictions there that our
operators have (TopK's K < 3840, ScatterND without `reduction`, GridSample on 4-D inputs).
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from litevloc.models.conformance import compare_outputs, model_outputs

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


def test_every_model_uses_only_operators_tensorrt_parses(model_cache: Path) -> None:
    for path in _onnx_files(model_cache):
        proto = onnx.load(str(path))
        opset = next(o.version for o in proto.opset_import if o.domain in ("", "ai.onnx"))
        assert opset in TENSORRT_OPSETS, f"{path.name}: opset {opset}"
        ops = {n.op_type for n in proto.graph.node}
        assert ops <= TENSORRT_ONNX_OPS, f"{path.name}: {sorted(ops - TENSORRT_ONNX_OPS)} not in TensorRT's parser"
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


def _frames(seven_scenes_dir: Path) -> list[np.ndarray]:
    frames = []
    for i in (0, 10):
        bgr = cv2.imread(str(seven_scenes_dir / f"frame-{i:06d}.color.jpg"))
        assert bgr is not None
        frames.append(np.asarray(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), np.uint8))
    return frames


def test_compare_outputs_accepts_a_reordered_run_and_names_what_moved() -> None:
    rng = np.random.default_rng(0)
    kp = rng.uniform(0, 300, (50, 2)).astype(np.float32)
    desc = rng.normal(size=(50, 8)).astype(np.float32)
    a = {"x/0/keypoints": kp, "x/0/descriptors": desc, "x/0/scores": np.ones(50, np.float32),
         "v/0/descriptor": desc[0], "m/pairs": np.hstack((kp, kp))[:20], "m/scores": np.ones(20, np.float32)}
    order = rng.permutation(50)
    b = {**a, "x/0/keypoints": kp[order], "x/0/descriptors": desc[order]}
    assert compare_outputs(a, b) == []
    moved = {**a, "x/0/descriptors": desc + np.float32(1e-3)}
    assert [d.key for d in compare_outputs(a, moved)] == ["x/0/descriptors"]
    shifted = {**a, "x/0/keypoints": kp + np.float32(0.01)}
    assert [d.key for d in compare_outputs(a, shifted)] == ["x/0/keypoints"]
    fewer = {**a, "m/pairs": a["m/pairs"][:15], "m/scores": a["m/scores"][:15]}
    assert [d.key for d in compare_outputs(a, fewer)] == ["m/pairs"]
    assert [d.key for d in compare_outputs(a, {**a, "v/0/descriptor": desc[1]})] == ["v/0/descriptor"]
    missing = dict(a)
    del missing["v/0/descriptor"]
    assert [d.key for d in compare_outputs(a, missing)] == ["v/0/descriptor"]


@pytest.mark.shared_data
def test_older_onnxruntime_builds_give_the_newest_outputs(model_cache: Path, seven_scenes_dir: Path,
                                                          tmp_path: Path) -> None:
    builds = sorted((Path(sys.prefix) / "ort").glob("1.*"))
    versions = {p.name.rsplit(".", 1)[0] for p in builds}
    assert {"1.20", "1.23"} <= versions, (
        f"older onnxruntime builds missing under {Path(sys.prefix) / 'ort'} (have {sorted(versions)}): "
        "`make install-dev` installs them")
    images = []
    for i, img in enumerate(_frames(seven_scenes_dir)):
        images.append(tmp_path / f"{i}.png")
        cv2.imwrite(str(images[-1]), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
    ref = model_outputs(model_cache, _frames(seven_scenes_dir))
    ref_path = tmp_path / "newest.npz"
    np.savez(ref_path, **ref)
    for build in builds:
        proc = subprocess.run(
            [sys.executable, "-m", "litevloc.models.conformance", "--cache", str(model_cache),
             "--images", *map(str, images), "--against", str(ref_path)],
            env={**os.environ, "PYTHONPATH": str(build)},
            capture_output=True, text=True, timeout=240)
        assert f"onnxruntime {build.name}" in proc.stderr, proc.stderr[-2000:]
        assert proc.returncode == 0, f"onnxruntime {build.name}:\n{proc.stdout}{proc.stderr[-2000:]}"

