"""Execution providers without a GPU: `onnxruntime.get_available_providers` and
`onnxruntime.InferenceSession` faked, to check what a Jetson's sessions would be given (provider
names and options, TensorRT's caches and LightGlue's shape profiles), that a provider asked for and
missing is one WARNING and a WARN diagnostics entry, and that CPU is always last."""

from __future__ import annotations

import logging
from collections.abc import Iterator
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import onnxruntime as ort
import pytest

from litevloc.base.params.models import MIB, CudaConfig, ModelsConfig, TensorrtConfig
from litevloc.config.schema import DiagnosticsConfig, RuntimeConfig
from litevloc.models import ort as mort
from litevloc.models.registry import load_extractor, load_matcher, load_place_recognizer
from litevloc.models.types import ProviderState
from litevloc.runtime.service.diagnostics import OK, WARN, diagnostic_statuses
from tests.runtime.fakes import FakeFusion, FakePublisher, FakeVloc, SyntheticSource, make_service

GPU = ["TensorrtExecutionProvider", "CUDAExecutionProvider", "CPUExecutionProvider"]
_REAL_SESSION = ort.InferenceSession


class FakeSession:
    """Records what `make_session` asks for; runs on a real CPU session. `get_providers` says the
    session took every provider asked for, unless `refuse` names ones whose libraries "failed"."""

    calls: ClassVar[list[tuple[str, list[Any]]]] = []
    refuse: ClassVar[set[str]] = set()

    def __init__(self, path: str, sess_options: Any = None, providers: list[Any] | None = None) -> None:
        self.asked = list(providers or [])
        FakeSession.calls.append((Path(path).name, self.asked))
        self._real = _REAL_SESSION(path, sess_options=sess_options, providers=["CPUExecutionProvider"])

    def get_providers(self) -> list[str]:
        names = [p[0] if isinstance(p, tuple) else p for p in self.asked]
        return [n for n in names if n not in FakeSession.refuse]

    def __getattr__(self, name: str) -> Any:
        return getattr(self._real, name)


@pytest.fixture(autouse=True)
def _fresh_reports() -> Iterator[None]:
    mort.clear_session_reports()
    FakeSession.calls, FakeSession.refuse = [], set()
    yield
    mort.clear_session_reports()


@pytest.fixture
def cache(model_cache: Path, tmp_path: Path) -> Path:
    """The model cache's files linked into a folder of this test (TensorRT's cache folders go there)."""
    d = tmp_path / "models"
    d.mkdir()
    for f in model_cache.iterdir():
        if f.is_file():
            (d / f.name).symlink_to(f)
    return d


def fake_gpu(monkeypatch: pytest.MonkeyPatch, available: list[str] = GPU) -> None:
    monkeypatch.setattr(ort, "get_available_providers", lambda: list(available))
    monkeypatch.setattr(ort, "InferenceSession", FakeSession)
    mort.clear_session_reports()  # the cached build read the real provider list


def model_calls() -> list[tuple[str, list[tuple[str, dict[str, str]]]]]:
    """The sessions `make_session` made (the profile reader's plain CPU sessions left out)."""
    return [(f, p) for f, p in FakeSession.calls if p and isinstance(p[0], tuple)]


def test_tensorrt_and_cuda_options_reach_the_session_with_onnxruntime_names(
    monkeypatch: pytest.MonkeyPatch, cache: Path
) -> None:
    fake_gpu(monkeypatch)
    cfg = ModelsConfig(cache_dir=str(cache), providers=("tensorrt", "cuda", "cpu"),
                       tensorrt=TensorrtConfig(device_id=1, fp16=False, max_workspace_mib=512),
                       cuda=CudaConfig(device_id=1, cudnn_conv_algo_search="EXHAUSTIVE", gpu_mem_limit_mib=256))
    load_extractor("aliked-n16", cfg)
    [(name, providers)] = model_calls()
    assert name == "aliked-n16-240x320-k512.onnx"
    assert [p for p, _ in providers] == GPU
    trt, cuda, cpu = (o for _, o in providers)
    assert trt == {
        "device_id": "1",
        "trt_fp16_enable": "False",
        "trt_max_workspace_size": str(512 * MIB),
        "trt_engine_cache_enable": "True",
        "trt_engine_cache_path": str(cache / "trt-engines"),
        "trt_timing_cache_enable": "True",
        "trt_timing_cache_path": str(cache / "trt-timing"),
    }  # a static-shape model: no profile
    assert (cache / "trt-engines").is_dir() and (cache / "trt-timing").is_dir()
    assert cuda == {"device_id": "1", "cudnn_conv_algo_search": "EXHAUSTIVE",
                    "arena_extend_strategy": "kSameAsRequested", "gpu_mem_limit": str(256 * MIB)}
    assert cpu == {}
    r = mort.provider_report()
    assert r.state is ProviderState.AS_ASKED and r.models[0].used == ("TensorrtExecutionProvider",)


def test_engine_and_timing_caches_follow_their_settings(monkeypatch: pytest.MonkeyPatch, cache: Path,
                                                       tmp_path: Path) -> None:
    fake_gpu(monkeypatch)
    cfg = ModelsConfig(cache_dir=str(cache), providers=("tensorrt",),
                       tensorrt=TensorrtConfig(engine_cache_dir="engines-here", timing_cache_dir=str(tmp_path / "t"),
                                               timing_cache=True, engine_cache=True))
    load_place_recognizer("effnet-gem", cfg)
    [(_, providers)] = model_calls()
    trt = providers[0][1]
    assert trt["trt_engine_cache_path"] == str(cache / "engines-here")  # relative: under the model cache
    assert trt["trt_timing_cache_path"] == str(tmp_path / "t")
    assert [p for p, _ in providers] == ["TensorrtExecutionProvider", "CPUExecutionProvider"]
    mort.clear_session_reports()
    FakeSession.calls = []
    off = ModelsConfig(cache_dir=str(cache), providers=("tensorrt",),
                       tensorrt=TensorrtConfig(engine_cache=False, timing_cache=False))
    load_place_recognizer("effnet-gem", off)
    trt = model_calls()[0][1][0][1]
    assert trt["trt_engine_cache_enable"] == "False" and "trt_engine_cache_path" not in trt
    assert trt["trt_timing_cache_enable"] == "False" and "trt_timing_cache_path" not in trt


def test_lightglue_gets_one_profile_from_1_to_the_largest_keypoint_count(
    monkeypatch: pytest.MonkeyPatch, cache: Path
) -> None:
    """Every adaptive LightGlue part and the full model: min 1, opt the first look's match count
    (match_max_keypoints 384 of 512), max the second look's 2048, on each keypoint axis of the ONNX inputs."""
    fake_gpu(monkeypatch)
    cfg = ModelsConfig(cache_dir=str(cache), providers=("tensorrt", "cuda"))
    load_matcher("lightglue-adaptive", cfg)
    load_matcher("lightglue", cfg)
    calls = dict(model_calls())
    assert len(calls) == 1 + 9 + 9 + 1

    def shapes(name: str) -> tuple[str, str, str]:
        o = calls[name][0][1]
        return o["trt_profile_min_shapes"], o["trt_profile_opt_shapes"], o["trt_profile_max_shapes"]

    def kp(n: int) -> str:
        return f"kpts0:1x{n}x2,kpts1:1x{n}x2,desc0:1x{n}x128,desc1:1x{n}x128"

    assert shapes("lightglue-aliked.onnx") == (kp(1), kp(384), kp(2048))
    assert shapes("lightglue-aliked-adaptive.encoder.onnx") == (kp(1), kp(384), kp(2048))
    for i in range(9):
        n = 2048
        assert shapes(f"lightglue-aliked-adaptive.layer{i}.onnx")[2] == (
            f"d0:1x{n}x256,d1:1x{n}x256,e0:2x1x1x{n}x64,e1:2x1x1x{n}x64")
        assert shapes(f"lightglue-aliked-adaptive.head{i}.onnx") == (
            "d0:1x1x256,d1:1x1x256", "d0:1x384x256,d1:1x384x256", "d0:1x2048x256,d1:1x2048x256")
    # the CUDA provider takes no profile
    assert all("trt_profile_max_shapes" not in p[1][1] for p in calls.values())
    FakeSession.calls = []
    small = ModelsConfig(cache_dir=str(cache), providers=("tensorrt",), match_max_keypoints=0,
                         tensorrt=TensorrtConfig(profile_max_keypoints=1000))
    load_matcher("lightglue", small)
    assert model_calls()[0][1][0][1]["trt_profile_max_shapes"] == kp(1000)
    assert model_calls()[0][1][0][1]["trt_profile_opt_shapes"] == kp(512)


def test_profile_shapes_from_inputs() -> None:
    inputs: list[tuple[str, list[int | str | None]]] = [("kpts0", [None, "M", 2]), ("e0", [2, 1, 1, "M", 64])]
    got = mort.trt_profile_shapes(inputs, 100, 10)
    assert got == {"trt_profile_min_shapes": "kpts0:1x1x2,e0:2x1x1x1x64",
                   "trt_profile_opt_shapes": "kpts0:1x10x2,e0:2x1x1x10x64",
                   "trt_profile_max_shapes": "kpts0:1x100x2,e0:2x1x1x100x64"}
    assert mort.trt_profile_shapes([("image", [1, 3, 240, 320])], 100, 10) == {}
    with pytest.raises(ValueError):
        mort.trt_profile_shapes(inputs, 10, 100)


def test_the_adaptive_matcher_with_profiles_gives_the_same_matches(monkeypatch: pytest.MonkeyPatch,
                                                                    cache: Path) -> None:
    """The profile changes what the session is given, not what it computes (here on CPU)."""
    from litevloc.models.types import Features

    rng = np.random.default_rng(0)

    def feats(n: int) -> Features:
        d = rng.standard_normal((n, 128)).astype(np.float32)
        return Features((rng.random((n, 2)) * [320, 240]).astype(np.float32),
                        d / np.linalg.norm(d, axis=1, keepdims=True), np.ones(n, np.float32), (320, 240))

    f0, f1 = feats(200), feats(150)
    plain = load_matcher("lightglue-adaptive", ModelsConfig(cache_dir=str(cache))).match(f0, f1)
    fake_gpu(monkeypatch)
    faked = load_matcher("lightglue-adaptive", ModelsConfig(cache_dir=str(cache), providers=("tensorrt",)))
    m = faked.match(f0, f1)
    np.testing.assert_array_equal(m.idx0, plain.idx0)
    np.testing.assert_array_equal(m.idx1, plain.idx1)


def test_a_missing_provider_is_one_warning_and_a_warn_diagnostics_entry(
    monkeypatch: pytest.MonkeyPatch, cache: Path, caplog: pytest.LogCaptureFixture
) -> None:
    fake_gpu(monkeypatch, ["CPUExecutionProvider"])
    cfg = ModelsConfig(cache_dir=str(cache), providers=("tensorrt", "cuda", "cpu"))
    with caplog.at_level(logging.INFO, logger="litevloc.models.ort"):
        load_extractor("aliked-n16", cfg)
        load_place_recognizer("effnet-gem", cfg)
        load_extractor("aliked-n16", cfg)
    warnings = [r for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == 2, [r.getMessage() for r in warnings]  # one per missing provider, not per session
    assert "TensorrtExecutionProvider" in warnings[0].getMessage()
    assert "CUDAExecutionProvider" in warnings[1].getMessage()
    assert all(p[-1][0] == "CPUExecutionProvider" and len(p) == 1 for _, p in model_calls())
    report = mort.provider_report()
    assert report.state is ProviderState.FALLBACK
    assert report.message.startswith("models: tensorrt asked for, running on CPUExecutionProvider")
    assert report.build.available == ("CPUExecutionProvider",)

    svc = make_service(SyntheticSource(), FakeVloc(), FakeFusion(), FakePublisher(),
                       RuntimeConfig(mode="sequential"), configure_thread_counts=False)
    assert "models" not in svc.status()
    svc.models_report = mort.provider_report
    status = svc.status()
    assert status["models"]["state"] == "fallback"
    assert status["models"]["sessions"]["aliked-n16-240x320-k512"]["used"] == ["CPUExecutionProvider"]
    entries = {e[1]: e for e in diagnostic_statuses(status, None, DiagnosticsConfig())}
    lvl, _, msg, _, values = entries["litevloc/models"]
    assert lvl == WARN and msg == report.message
    assert dict(values)["provider/effnet-gem-240x320"] == "CPUExecutionProvider"
    assert dict(values)["distribution"] == report.build.distribution


def test_all_providers_as_asked_is_an_ok_entry(monkeypatch: pytest.MonkeyPatch, cache: Path) -> None:
    fake_gpu(monkeypatch)
    load_place_recognizer("effnet-gem", ModelsConfig(cache_dir=str(cache), providers=("cuda", "cpu")))
    status = {"models": mort.provider_report().as_dict()}
    entries = {e[1]: e for e in diagnostic_statuses(status, None, DiagnosticsConfig())}
    assert entries["litevloc/models"][0] == OK
    assert entries["litevloc/models"][2] == "models: all on CUDAExecutionProvider"


def test_a_provider_the_session_did_not_take_is_a_warning_and_a_fallback(
    monkeypatch: pytest.MonkeyPatch, cache: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """Available in the build but refused by the session (e.g. libnvinfer missing): still reported."""
    fake_gpu(monkeypatch)
    FakeSession.refuse = {"TensorrtExecutionProvider"}
    with caplog.at_level(logging.WARNING, logger="litevloc.models.ort"):
        load_place_recognizer("effnet-gem", ModelsConfig(cache_dir=str(cache), providers=("tensorrt", "cuda")))
    assert len(caplog.records) == 1 and "could not start TensorrtExecutionProvider" in caplog.records[0].getMessage()
    r = mort.provider_report()
    assert r.state is ProviderState.FALLBACK and r.models[0].used == ("CUDAExecutionProvider",)


def test_cpu_is_always_last(monkeypatch: pytest.MonkeyPatch) -> None:
    fake_gpu(monkeypatch)
    assert mort.resolve_providers(["cpu", "tensorrt", "cuda"]) == GPU
    assert mort.resolve_providers(["cuda", "cuda"]) == GPU[1:]
    assert mort.resolve_providers(["tensorrt"]) == [GPU[0], GPU[2]]
    setup = mort.ProviderSetup(("cpu", "cuda"))
    assert [p for p, _ in mort.session_providers(setup)] == GPU[1:]


def test_the_start_up_log_names_the_build_and_each_models_provider(
    monkeypatch: pytest.MonkeyPatch, cache: Path, caplog: pytest.LogCaptureFixture
) -> None:
    from litevloc.runtime.service.app import log_provider_report

    fake_gpu(monkeypatch, ["CPUExecutionProvider"])
    load_place_recognizer("effnet-gem", ModelsConfig(cache_dir=str(cache), providers=("tensorrt", "cpu")))
    with caplog.at_level(logging.INFO, logger="litevloc.runtime.service.app"):
        log_provider_report(mort.provider_report())
    [info, warning] = [r for r in caplog.records if r.name == "litevloc.runtime.service.app"]
    assert info.levelno == logging.INFO and f"onnxruntime {ort.__version__}" in info.getMessage()
    assert "effnet-gem-240x320 on CPUExecutionProvider" in info.getMessage()
    assert warning.levelno == logging.WARNING and "tensorrt asked for, running on CPU" in warning.getMessage()


def test_an_unwritable_engine_cache_is_a_user_error_naming_the_setting(monkeypatch: pytest.MonkeyPatch,
                                                                       cache: Path) -> None:
    fake_gpu(monkeypatch)
    (cache / "a-file").write_text("")
    cfg = ModelsConfig(cache_dir=str(cache), providers=("tensorrt",),
                       tensorrt=TensorrtConfig(engine_cache_dir=str(cache / "a-file" / "engines")))
    with pytest.raises(mort.ProviderError, match=r"models\.tensorrt\.engine_cache_dir"):
        load_place_recognizer("effnet-gem", cfg)


def test_a_cpu_build_installed_over_the_gpu_build_is_a_warning_and_a_warn_entry(
    monkeypatch: pytest.MonkeyPatch, cache: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """`pip install onnxruntime` after NVIDIA's onnxruntime-gpu: one import, two distributions."""
    from litevloc.runtime.service.app import log_provider_report

    versions = {"onnxruntime-gpu": "1.23.0", "onnxruntime": ort.__version__}

    def version(name: str) -> str:
        if name in versions:
            return versions[name]
        raise mort.importlib.metadata.PackageNotFoundError(name)

    monkeypatch.setattr(mort.importlib.metadata, "version", version)
    fake_gpu(monkeypatch, ["CPUExecutionProvider"])
    load_place_recognizer("effnet-gem", ModelsConfig(cache_dir=str(cache), providers=("cpu",)))
    report = mort.provider_report()
    assert report.state is ProviderState.DISTRIBUTION_CLASH
    assert report.build.installed == ("onnxruntime-gpu 1.23.0", f"onnxruntime {ort.__version__}")
    assert report.build.distribution == "onnxruntime"  # the one whose version is the imported module's
    assert "onnxruntime-gpu 1.23.0 and onnxruntime" in report.message
    with caplog.at_level(logging.INFO, logger="litevloc.runtime.service.app"):
        log_provider_report(report)
    levels = [r.levelno for r in caplog.records if r.name == "litevloc.runtime.service.app"]
    assert levels == [logging.INFO, logging.WARNING]
    entries = {e[1]: e for e in diagnostic_statuses({"models": report.as_dict()}, None, DiagnosticsConfig())}
    assert entries["litevloc/models"][0] == WARN
