"""bench/gpu.py: a provider this onnxruntime lacks is skipped with the reason, not a crash; CPU is measured."""

from __future__ import annotations

from litevloc.config import load_config
from tests.bench import load_bench


def test_an_unavailable_provider_is_skipped_with_the_reason() -> None:
    import onnxruntime as ort

    if "TensorrtExecutionProvider" in ort.get_available_providers():
        return  # a GPU build: nothing to skip
    gpu = load_bench("gpu")
    r = gpu.one_provider("tensorrt", load_config("default"), None, None, 0, 1)
    assert r["status"] == "skipped" and "TensorrtExecutionProvider is not in this onnxruntime" in r["reason"]


def test_cpu_latency_per_model() -> None:
    """On the default model cache (`make models`; the model tests export it)."""
    gpu = load_bench("gpu")
    cfg = load_config("default", ["localization.second_look.candidates=0", "models.tensorrt.profile_max_keypoints=64"])
    r = gpu.one_provider("cpu", cfg, None, None, 0, 1)
    assert r["status"] == "ok" and [m["role"] for m in r["models"]] == ["extractor", "matcher", "vpr"]
    assert all(m["providers"] == ["CPUExecutionProvider"] and m["steady_ms"] > 0 for m in r["models"])
