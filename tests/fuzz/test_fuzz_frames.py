"""Images of odd sizes and types into the frame path: the guard in front of VLoc turns a bad
frame into a counted rejection; frames it lets through are handled by the real models."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from litevloc.config.schema import RuntimeConfig
from litevloc.hw.messages import RgbdFrame
from litevloc.runtime.service.frame_guard import MAX_SIDE, MIN_SIDE, FrameGuard, frame_problem
from tests.runtime.fakes import FakeFusion, FakePublisher, SyntheticSource, make_service

K = np.array([[100.0, 0, 50], [0, 100.0, 40], [0, 0, 1]])
DTYPES = ["uint8", "uint16", "int8", "float32", "float64", "bool", "int64"]


@st.composite
def odd_frames(draw: Any) -> RgbdFrame:
    h = draw(st.sampled_from([0, 1, 7, 31, 32, 33, 48, 100, 4097]))
    w = draw(st.sampled_from([0, 1, 7, 31, 32, 33, 64, 100, 4097]))
    ch = draw(st.sampled_from([None, 1, 2, 3, 4]))
    shape = (h, w) if ch is None else (h, w, ch)
    if h * w > 5_000_000:  # keep memory sane: big sides only as thin strips
        shape = (h, 1) if ch is None else (h, 1, ch)
    color = np.zeros(shape, dtype=draw(st.sampled_from(DTYPES)))
    dshape = draw(st.sampled_from(["same", "none", "transposed", "3d"]))
    ddtype = draw(st.sampled_from(["float32", "float64", "uint16", "float16"]))
    hh, ww = color.shape[:2]
    depth = {"same": lambda: np.full((hh, ww), 1.0, ddtype), "none": lambda: None,
             "transposed": lambda: np.ones((ww, hh), ddtype), "3d": lambda: np.ones((hh, ww, 1), ddtype)}[dshape]()
    k = draw(st.sampled_from(["ok", "nan", "zero_f", "bad_row", "shape"]))
    KK = {"ok": K, "nan": K * np.nan, "zero_f": np.diag([0.0, 0.0, 1.0]),
          "bad_row": K + np.array([[0, 0, 0], [0, 0, 0], [0, 1, 0]]), "shape": np.eye(4)}[k]
    return RgbdFrame(draw(st.integers(0, 2**62)), color, depth, KK)


@settings(max_examples=300)
@given(odd_frames())
def test_guard_never_raises_and_only_passes_valid_frames(count_case: Any, frame: RgbdFrame) -> None:
    count_case()
    seen: list[RgbdFrame] = []

    def inner(f: RgbdFrame, prior: Any) -> str:
        seen.append(f)
        return "called"

    g = FrameGuard(inner)
    out = g(frame, None)
    if seen:
        f = seen[0]
        assert out == "called" and frame_problem(f) is None
        assert f.color.dtype == np.uint8 and f.color.ndim == 3 and f.color.shape[2] == 3
        assert MIN_SIDE <= f.color.shape[0] <= MAX_SIDE and MIN_SIDE <= f.color.shape[1] <= MAX_SIDE
        assert f.depth is not None and f.depth.dtype == np.float32 and f.depth.shape == f.color.shape[:2]
    else:
        assert not out.accepted and out.reason.startswith("bad frame: ") and sum(g.skipped.values()) == 1


@pytest.fixture(scope="module")
def bundle() -> Any:
    from litevloc.base.params.models import ModelsConfig
    from litevloc.models.catalog import DEFAULT_EXPORTS
    from litevloc.models.registry import default_cache_dir, read_manifest
    from litevloc.runtime.vloc_models import load_bundle

    cache = default_cache_dir()
    try:
        from litevloc.models.export.exporter import export_models
    except ImportError:  # a runtime-only install (no torch): only an absent export may skip
        missing = [m for m in DEFAULT_EXPORTS if m not in read_manifest(cache)["models"]]
        if missing:
            pytest.skip(f"models {missing} not exported in {cache} and torch is absent")
    else:
        export_models(DEFAULT_EXPORTS, cache)  # as `make test` does first: a no-op when current
    # a model that is present but wrong (checksum, export version) fails here instead of skipping
    return load_bundle(ModelsConfig(intra_op_threads=1))


@settings(max_examples=12)
@given(h=st.integers(MIN_SIDE, 700), w=st.integers(MIN_SIDE, 900), seed=st.integers(0, 3),
       kind=st.sampled_from(["noise", "flat", "stripes"]))
def test_real_models_on_odd_valid_sizes(bundle: Any, count_case: Any, h: int, w: int, seed: int, kind: str) -> None:
    """Sizes the guard lets through go through the real extractor and VPR model."""
    count_case()
    rng = np.random.default_rng(seed)
    img = {"noise": lambda: rng.integers(0, 256, (h, w, 3), dtype=np.uint8),
           "flat": lambda: np.full((h, w, 3), 200, np.uint8),
           "stripes": lambda: np.repeat((np.arange(w) % 16 < 8).astype(np.uint8)[None, :, None] * 255, h, 0)
           .repeat(3, 2)}[kind]()
    f = bundle.extract(img)
    kp = np.asarray(f.keypoints)
    assert kp.ndim == 2 and kp.shape[1] == 2 and np.all(np.isfinite(kp))
    if len(kp):  # keypoints in the image that was given, not the resized one
        assert kp[:, 0].min() >= -0.5 and kp[:, 0].max() <= w - 0.5 and kp[:, 1].max() <= h - 0.5
    d = np.asarray(bundle.describe(img))
    assert d.ndim == 1 and np.all(np.isfinite(d)) and abs(float(np.linalg.norm(d)) - 1.0) < 1e-3


@pytest.mark.timeout(30)
def test_service_survives_bad_frames() -> None:
    """Bad frames in a live stream: counted rejections with their reason, the service keeps running."""
    src = SyntheticSource(seconds=1.0)
    bad = [RgbdFrame(m.t_ns, np.zeros((8, 8), np.uint16), None, m.K, index=m.index) if isinstance(m, RgbdFrame)
           else m for m in src.msgs]
    src.msgs = bad
    fusion = FakeFusion()

    def never(frame: RgbdFrame, prior: Any) -> Any:
        raise AssertionError("a bad frame reached VLoc")

    svc = make_service(src, FrameGuard(never), fusion, FakePublisher(),
                       RuntimeConfig(mode="deterministic"), rate=0.0, configure_thread_counts=False)
    res = svc.run(timeout_s=20)
    assert res.ok and res.reason == "end of source"
    c = res.status["counters"]
    assert c["vloc_rejected"] == src.frame_count() and res.status["last_vloc_reason"] == "bad frame: bad colour shape"
