"""The `models` config section and onnxruntime session settings."""

from __future__ import annotations

from pathlib import Path

import pytest

from litevloc.base.loader import ConfigError
from litevloc.base.params.models import ModelsConfig
from litevloc.config import load_config
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
    assert not so.enable_mem_pattern  # its per-shape block sits on top of the shared arena (RSS)


_ARENA_PROBE = """
import sys
import numpy as np
from litevloc.base.params.models import ModelsConfig
from litevloc.base.process_usage import memory_mb
from litevloc.models.ort import make_session
from litevloc.models.registry import locate

def rss_mb():
    return memory_mb()["rss"]

path, _ = locate("aliked-n16-240x320-k512", ModelsConfig(cache_dir=sys.argv[1]))
sessions = [make_session(path, ("cpu",), 1) for _ in range(3)]
inp = sessions[0].get_inputs()[0]
x = np.random.default_rng(0).random([d if isinstance(d, int) else 1 for d in inp.shape], dtype=np.float32)
outs, grew = [], []
for s in sessions:
    before = rss_mb()
    outs.append(s.run(None, {inp.name: x}))
    grew.append(rss_mb() - before)
for o in outs[1:]:
    for u, v in zip(outs[0], o, strict=True):
        np.testing.assert_allclose(u, v, rtol=1e-4, atol=1e-4)
print(" ".join(f"{g:.1f}" for g in grew))
"""


def test_sessions_share_one_cpu_arena(model_cache: Path) -> None:
    """Three sessions made by `make_session` draw their working memory from the one process-wide
    arena: the first run grows it (~150 MB for ALIKED-n16 at 240x320), the other sessions' first
    runs reuse it (each session's own arena would grow by as much again), and all three agree."""
    import subprocess
    import sys

    r = subprocess.run([sys.executable, "-c", _ARENA_PROBE, str(model_cache)], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    first, *others = (float(v) for v in r.stdout.split())
    assert first > 50, first  # the probe's model does need a large arena
    assert all(g < 0.2 * first for g in others), (first, others)
