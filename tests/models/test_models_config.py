"""The `models` config section and onnxruntime session settings."""

from __future__ import annotations

from pathlib import Path

import pytest

from litevloc.base.params.models import ModelsConfig
from litevloc.config import ConfigError, load_config
from litevloc.models.ort import make_session, resolve_providers
from litevloc.models.registry import locate


def test_models_section_loads_and_validates() -> None:
    cfg = load_config(
        None,
        [
            "models.intra_op_threads=1",
            "models.providers=[cuda, cpu]",
            "models.extractor_size=[480, 640]",
        ],
    ).models
    assert cfg.intra_op_threads == 1 and cfg.providers == ("cuda", "cpu")
    assert cfg.extractor_size == (480, 640)
    for bad in (
        "models.extractor=superpoint",
        "models.intra_op_threads=0",
        "models.ratio=1.5",
        "models.providers=[]",
        "models.unknown=1",
    ):
        with pytest.raises(ConfigError):
            load_config(None, [bad])


def test_provider_resolution_falls_back_to_cpu() -> None:
    import onnxruntime as ort

    got = resolve_providers(["tensorrt", "cuda", "cpu"])
    assert got[-1] == "CPUExecutionProvider"
    assert set(got) <= set(ort.get_available_providers())
    with pytest.raises(ValueError, match="unknown execution provider"):
        resolve_providers(["tpu"])


def test_session_threads_and_optimisation(model_cache: Path) -> None:
    import onnxruntime as ort

    path, _ = locate("aliked-t16-240x320-k512", ModelsConfig(cache_dir=str(model_cache)))
    sess = make_session(path, ("cpu",), 2)
    so = sess.get_session_options()
    assert so.intra_op_num_threads == 2 and so.inter_op_num_threads == 1
    assert so.graph_optimization_level == ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    assert sess.get_providers() == ["CPUExecutionProvider"]
    assert so.get_session_config_entry("session.use_env_allocators") == "1"


def test_sessions_share_one_cpu_arena(model_cache: Path) -> None:
    """Two sessions built by make_session run correctly on the one registered arena, and
    registering again is a no-op (ORT raises if the same allocator is registered twice)."""
    import numpy as np

    from litevloc.models.ort import register_shared_cpu_arena

    path, _ = locate("aliked-t16-240x320-k512", ModelsConfig(cache_dir=str(model_cache)))
    a = make_session(path, ("cpu",), 2)
    b = make_session(path, ("cpu",), 1)
    register_shared_cpu_arena()
    inp = a.get_inputs()[0]
    shape = [d if isinstance(d, int) else 1 for d in inp.shape]
    x = np.random.default_rng(0).random(shape, dtype=np.float32)
    out_a = a.run(None, {inp.name: x})
    out_b = b.run(None, {inp.name: x})
    for u, v in zip(out_a, out_b, strict=True):
        np.testing.assert_allclose(u, v, rtol=1e-4, atol=1e-4)
