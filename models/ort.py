"""onnxruntime session construction: providers and their options from config, explicit threads,
full graph optimisation, and a report of the provider each session actually runs on.

* `ProviderSetup` (from `ModelsConfig`: `provider_setup`) says which execution providers to ask
  for, in order, and with which options (`models.tensorrt`, `models.cuda`); CPU is always last.
* `make_session` passes them as ``providers=[(name, options), ...]``. A model with dynamic
  keypoint axes (LightGlue) gets explicit TensorRT optimisation profiles (`trt_profile_*_shapes`,
  from the ONNX inputs, 1 .. `profile_max_keypoints`): one engine covers every keypoint count
  (and the counts the adaptive matcher's pruning leaves), so it is built once and cached.
* A provider asked for and not available (or not taken by a session) is logged at WARNING, once
  per process per provider; `provider_report()` is the typed record of the build and of every
  session made (`ProviderReport`), which the service puts in its status and diagnostics.
"""

from __future__ import annotations

import importlib.metadata
import logging
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from litevloc.base.errors import LiteVLocError
from litevloc.base.params.models import MIB, CudaConfig, TensorrtConfig
from litevloc.models.types import OnnxRuntimeMissing, ProviderState

try:
    import onnxruntime as ort
except ImportError as exc:  # neither extra installed: a one-line user error where a model is first needed
    raise OnnxRuntimeMissing(
        "onnxruntime is not installed: pip install 'litevloc[cpu]' for the CPU build, or on a Jetson NVIDIA's "
        f"onnxruntime-gpu wheel first (docs/deployment.md) ({exc})") from exc

if TYPE_CHECKING:
    from litevloc.base.params.models import ModelsConfig

log = logging.getLogger(__name__)

_shared_cpu_arena_registered = False


def register_shared_cpu_arena() -> None:
    """Register one process-wide ORT CPU arena that every session of this process shares.

    Each `InferenceSession` otherwise grows its own CPU arena to the peak of its largest run
    and keeps it: with the extractor, the matcher's parts and the VPR model in one process the
    arenas add up. Measured on this machine (20 rounds of extract + match + describe): peak RSS
    612 -> 458 MB with the same speed (arena off altogether: 281 MB but 25 % slower).
    Idempotent; called by `make_session`.
    """
    global _shared_cpu_arena_registered
    if _shared_cpu_arena_registered:
        return
    mem_info = ort.OrtMemoryInfo(
        "Cpu", ort.OrtAllocatorType.ORT_ARENA_ALLOCATOR, 0, ort.OrtMemType.DEFAULT
    )
    # max_mem=0 (no cap), extend strategy -1 / chunk sizes -1: ORT's defaults.
    ort.create_and_register_allocator(mem_info, ort.OrtArenaCfg(0, -1, -1, -1))
    _shared_cpu_arena_registered = True


CPU = "CPUExecutionProvider"
CUDA = "CUDAExecutionProvider"
TENSORRT = "TensorrtExecutionProvider"
PROVIDER_NAMES = {"cpu": CPU, "cuda": CUDA, "tensorrt": TENSORRT}
SHORT_NAMES = {v: k for k, v in PROVIDER_NAMES.items()}
ENGINE_CACHE_DIR = "trt-engines"  # under the model cache, when models.tensorrt.engine_cache_dir is ""
TIMING_CACHE_DIR = "trt-timing"  # under the model cache, when models.tensorrt.timing_cache_dir is ""

_warned: set[str] = set()  # providers already reported missing (one WARNING per process each)
_lock = threading.Lock()
_sessions: list[SessionReport] = []


class ProviderError(LiteVLocError, RuntimeError):
    """A provider's settings cannot be applied (e.g. TensorRT's cache folder cannot be created)."""


@dataclass(frozen=True)
class ProviderSetup:
    """Which onnxruntime execution providers a session asks for and how they are configured.

    providers: config names (cpu / cuda / tensorrt) in order of preference; cache_dir: the model
    cache (the default home of TensorRT's engine and timing caches); profile_*_keypoints: the
    keypoint counts of TensorRT's optimisation profile for models with a dynamic keypoint axis
    (the largest count and the one kernels are tuned for)."""

    providers: tuple[str, ...] = ("cpu",)
    tensorrt: TensorrtConfig = field(default_factory=TensorrtConfig)
    cuda: CudaConfig = field(default_factory=CudaConfig)
    cache_dir: Path | None = None
    profile_max_keypoints: int = 2048
    profile_opt_keypoints: int = 512


def provider_setup(cfg: ModelsConfig, cache_dir: Path | None = None) -> ProviderSetup:
    """The `ProviderSetup` of a `models` config section (`cache_dir`: the model cache in use)."""
    return ProviderSetup(
        tuple(cfg.providers), cfg.tensorrt, cfg.cuda, cache_dir, cfg.profile_max_keypoints, cfg.profile_opt_keypoints
    )


def _as_setup(providers: Sequence[str] | ProviderSetup) -> ProviderSetup:
    return providers if isinstance(providers, ProviderSetup) else ProviderSetup(tuple(providers))


def available_providers() -> list[str]:
    """onnxruntime's available execution providers in this process (its own order)."""
    return list(ort.get_available_providers())


def _warn_once(provider: str, text: str) -> None:
    with _lock:
        if provider in _warned:
            return
        _warned.add(provider)
    log.warning(text)


def resolve_providers(wanted: Sequence[str]) -> list[str]:
    """Config names (cpu/cuda/tensorrt) -> available ORT provider names, CPU always last.

    A provider asked for and not available is logged at WARNING (once per process per provider)
    and left out. ValueError on an unknown name."""
    available = set(available_providers())
    out: list[str] = []
    missing: list[str] = []
    for name in wanted:
        if name not in PROVIDER_NAMES:
            raise ValueError(
                f"unknown execution provider {name!r}; known: {sorted(PROVIDER_NAMES)}"
            )
        full = PROVIDER_NAMES[name]
        if full not in available:
            missing.append(full)
        elif full not in out:
            out.append(full)
    if CPU in out:
        out.remove(CPU)
    out.append(CPU)
    for full in missing:
        build = ort_build()
        _warn_once(
            full,
            f"models.providers asks for {SHORT_NAMES[full]} but onnxruntime has no {full} here "
            f"({build.distribution or 'onnxruntime'} {build.version}, available: {', '.join(build.available)}): "
            f"the models run on {out[0]}" + ("" if full == CPU else
                                            " (install onnxruntime-gpu with CUDA/TensorRT, e.g. JetPack's wheel)"),
        )
    return out


@dataclass(frozen=True)
class OrtBuild:
    """The onnxruntime this process runs: distribution (`onnxruntime`, `onnxruntime-gpu`, ...; "" when
    no installed distribution provides the module), version, `ort.get_device()` (CPU / GPU) and the
    available execution providers."""

    distribution: str
    version: str
    device: str
    available: tuple[str, ...]
    # every onnxruntime distribution installed ("onnxruntime-gpu 1.23.0", ...): more than one share
    # the import name `onnxruntime`, and the last one installed overwrote the other's files
    installed: tuple[str, ...] = ()


_DISTRIBUTIONS = ("onnxruntime-gpu", "onnxruntime", "onnxruntime-directml", "onnxruntime-openvino",
                  "onnxruntime-training", "ort-nightly-gpu", "ort-nightly")


_build: OrtBuild | None = None


def ort_build() -> OrtBuild:
    """The `OrtBuild` of this process (the distribution from importlib.metadata; computed once)."""
    global _build
    if _build is None:
        _build = _read_build()
    return _build


def _read_build() -> OrtBuild:
    installed: list[tuple[str, str]] = []
    for name in _DISTRIBUTIONS:
        try:
            installed.append((name, importlib.metadata.version(name)))
        except importlib.metadata.PackageNotFoundError:
            continue
    # the distribution whose version is the imported module's (the first such: -gpu before the CPU build)
    dist = next((n for n, v in installed if v == ort.__version__), installed[0][0] if installed else "")
    return OrtBuild(dist, str(ort.__version__), str(ort.get_device()), tuple(available_providers()),
                    tuple(f"{n} {v}" for n, v in installed))


@dataclass(frozen=True)
class SessionReport:
    """One session made by `make_session`: model id (the file name up to its first dot: the parts of
    adaptive LightGlue share one), file name, the ORT providers asked for (config order, available or
    not), the one it runs on (`session.get_providers()[0]`), and its construction time (s)."""

    model: str
    file: str
    asked: tuple[str, ...]
    used: str
    build_s: float

    @property
    def fell_back(self) -> bool:
        """The session does not run on the first provider asked for."""
        return bool(self.asked) and self.used != self.asked[0]


@dataclass(frozen=True)
class ModelRuntime:
    """Per model id: the providers its sessions run on (one unless its parts differ) and whether it fell back."""

    model: str
    used: tuple[str, ...]
    asked: tuple[str, ...]
    sessions: int
    build_s: float
    fell_back: bool


@dataclass(frozen=True)
class ProviderReport:
    """The onnxruntime build and the provider each model's sessions actually run on (`provider_report`)."""

    build: OrtBuild
    models: tuple[ModelRuntime, ...]
    state: ProviderState

    @property
    def message(self) -> str:
        """One line: "models: all on TensorrtExecutionProvider" or "models: tensorrt asked for, running
        on CPUExecutionProvider (aliked-..., lightglue-...)"."""
        if self.state is ProviderState.DISTRIBUTION_CLASH:
            return (f"models: {' and '.join(self.build.installed)} are installed together and share one import "
                    "(one overwrote the other): uninstall both, then install one (docs/deployment.md)")
        if self.state is ProviderState.NO_SESSIONS:
            return "models: no onnxruntime session yet"
        if self.state is ProviderState.AS_ASKED:
            used = sorted({u for m in self.models for u in m.used})
            return f"models: all on {', '.join(used)}"
        worst = [m for m in self.models if m.fell_back]
        asked = SHORT_NAMES.get(worst[0].asked[0], worst[0].asked[0])
        used = sorted({u for m in worst for u in m.used})
        return f"models: {asked} asked for, running on {', '.join(used)} ({', '.join(m.model for m in worst)})"

    @property
    def summary(self) -> str:
        """One line for the start-up log: the build, then each model's provider."""
        b = self.build
        models = "; ".join(f"{m.model} on {', '.join(m.used)}" for m in self.models) or "no ONNX session"
        return (f"onnxruntime {b.version} ({b.distribution or 'distribution unknown'}, device {b.device}, "
                f"providers {', '.join(b.available)}): {models}")

    def as_dict(self) -> dict[str, Any]:
        """JSON-able (the service status's `models` entry)."""
        b = self.build
        return {
            "state": self.state.value,
            "message": self.message,
            "onnxruntime": {"distribution": b.distribution, "version": b.version, "device": b.device,
                            "available": list(b.available), "installed": list(b.installed)},
            "sessions": {m.model: {"used": list(m.used), "asked": list(m.asked), "sessions": m.sessions,
                                   "build_s": round(m.build_s, 3), "fell_back": m.fell_back} for m in self.models},
        }


def provider_report(sessions: Sequence[SessionReport] | None = None) -> ProviderReport:
    """The `ProviderReport` of `sessions` (default: every session `make_session` made in this process)."""
    reports = list(session_reports() if sessions is None else sessions)
    by_model: dict[str, list[SessionReport]] = {}
    for s in reports:
        by_model.setdefault(s.model, []).append(s)
    models = tuple(
        ModelRuntime(name, tuple(dict.fromkeys(s.used for s in ss)), ss[0].asked, len(ss),
                     sum(s.build_s for s in ss), any(s.fell_back for s in ss))
        for name, ss in by_model.items()
    )
    build = ort_build()
    if len(build.installed) > 1:
        state = ProviderState.DISTRIBUTION_CLASH
    elif not models:
        state = ProviderState.NO_SESSIONS
    elif any(m.fell_back for m in models):
        state = ProviderState.FALLBACK
    else:
        state = ProviderState.AS_ASKED
    return ProviderReport(build, models, state)


def session_reports() -> list[SessionReport]:
    """Every session `make_session` made in this process, in order."""
    with _lock:
        return list(_sessions)


def clear_session_reports() -> None:
    """Forget the sessions made so far and the providers already warned about (tests)."""
    global _build
    with _lock:
        _sessions.clear()
        _warned.clear()
        _build = None


def model_inputs(path: Path) -> list[tuple[str, list[int | str | None]]]:
    """(name, shape) of each input of the ONNX model at `path`, read by a CPU session without graph
    optimisation (dynamic axes are str or None)."""
    so = ort.SessionOptions()
    so.graph_optimization_level = ort.GraphOptimizationLevel.ORT_DISABLE_ALL
    so.log_severity_level = 3
    sess = ort.InferenceSession(str(path), sess_options=so, providers=[CPU])
    return [(i.name, list(i.shape)) for i in sess.get_inputs()]


def profile_shape(shape: Sequence[int | str | None], n: int) -> list[int]:
    """An input shape with every dynamic keypoint axis at `n` (a dynamic batch axis of a 3-D input at 1)."""
    dims = []
    for axis, d in enumerate(shape):
        if isinstance(d, int) and d >= 0:
            dims.append(d)
        elif axis == 0 and len(shape) == 3:  # (batch, N, C) with a dynamic batch: one image pair
            dims.append(1)
        else:  # a dynamic keypoint axis
            dims.append(n)
    return dims


def _shape_text(shape: Sequence[int | str | None], n: int) -> str:
    return "x".join(str(d) for d in profile_shape(shape, n))


def trt_profile_shapes(
    inputs: Sequence[tuple[str, Sequence[int | str | None]]], max_keypoints: int, opt_keypoints: int,
    min_keypoints: int = 1,
) -> dict[str, str]:
    """TensorRT's explicit optimisation profile for a model whose dynamic axes are keypoint counts
    (LightGlue: ``kpts0 (1, N, 2)``, ``desc0 (1, N, 128)``, the parts' ``d0 (1, N, 256)``,
    ``e0 (2, 1, 1, N, 32)``, ...): `trt_profile_{min,opt,max}_shapes` as ``name:dxdxd,...`` with every
    dynamic axis at min_keypoints / opt_keypoints / max_keypoints (a dynamic batch axis of a 3-D input
    at 1). {} when no input has a dynamic axis (static models need no profile)."""
    if not any(not (isinstance(d, int) and d >= 0) for _, shape in inputs for d in shape):
        return {}
    if not 1 <= min_keypoints <= opt_keypoints <= max_keypoints:
        raise ValueError(f"profile keypoints must satisfy 1 <= min <= opt <= max, got "
                         f"{min_keypoints}, {opt_keypoints}, {max_keypoints}")
    return {
        f"trt_profile_{kind}_shapes": ",".join(f"{name}:{_shape_text(shape, n)}" for name, shape in inputs)
        for kind, n in (("min", min_keypoints), ("opt", opt_keypoints), ("max", max_keypoints))
    }


def _flag(v: bool) -> str:
    return "True" if v else "False"


def _cache_folder(setting: str, default: str, cache_dir: Path | None) -> Path:
    base = cache_dir if cache_dir is not None else Path.cwd()
    if not setting:
        return base / default
    p = Path(setting).expanduser()
    return p if p.is_absolute() else base / p


def _make_folder(d: Path, setting: str) -> None:
    try:
        d.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ProviderError(f"cannot create TensorRT's cache folder {d} ({exc.strerror or exc}): "
                            f"set {setting} to a writable folder") from exc


def tensorrt_options(setup: ProviderSetup, path: Path | None = None, dynamic_keypoints: bool = False) -> dict[str, str]:
    """The TensorRT execution provider's options of `setup` (onnxruntime's names, string values).

    Engine and timing caches go to `tensorrt.engine_cache_dir` / `timing_cache_dir` ("" = `trt-engines`
    / `trt-timing` in the model cache; a relative path is under the model cache), created here.
    With `dynamic_keypoints` the optimisation profile comes from the inputs of the model at `path`.
    ProviderError when a cache folder cannot be created."""
    t = setup.tensorrt
    opts = {
        "device_id": str(t.device_id),
        "trt_fp16_enable": _flag(t.fp16),
        "trt_max_workspace_size": str(t.max_workspace_mib * MIB),
        "trt_engine_cache_enable": _flag(t.engine_cache),
        "trt_timing_cache_enable": _flag(t.timing_cache),
    }
    if t.engine_cache:
        d = _cache_folder(t.engine_cache_dir, ENGINE_CACHE_DIR, setup.cache_dir)
        _make_folder(d, "models.tensorrt.engine_cache_dir")
        opts["trt_engine_cache_path"] = str(d)
    if t.timing_cache:
        d = _cache_folder(t.timing_cache_dir, TIMING_CACHE_DIR, setup.cache_dir)
        _make_folder(d, "models.tensorrt.timing_cache_dir")
        opts["trt_timing_cache_path"] = str(d)
    if dynamic_keypoints and path is not None:
        n_max = setup.profile_max_keypoints
        opts.update(trt_profile_shapes(model_inputs(path), n_max, max(1, min(setup.profile_opt_keypoints, n_max))))
    return opts


def cuda_options(cfg: CudaConfig) -> dict[str, str]:
    """The CUDA execution provider's options of `cfg` (onnxruntime's names, string values)."""
    opts = {
        "device_id": str(cfg.device_id),
        "cudnn_conv_algo_search": cfg.cudnn_conv_algo_search,
        "arena_extend_strategy": cfg.arena_extend_strategy,
    }
    if cfg.gpu_mem_limit_mib > 0:
        opts["gpu_mem_limit"] = str(cfg.gpu_mem_limit_mib * MIB)
    return opts


def session_providers(
    setup: ProviderSetup, path: Path | None = None, dynamic_keypoints: bool = False
) -> list[tuple[str, dict[str, str]]]:
    """``[(ORT provider name, options), ...]`` for `InferenceSession`: the available providers of
    `setup.providers` in order, CPU last (`resolve_providers`), each with its options."""
    out: list[tuple[str, dict[str, str]]] = []
    for name in resolve_providers(setup.providers):
        if name == TENSORRT:
            out.append((name, tensorrt_options(setup, path, dynamic_keypoints)))
        elif name == CUDA:
            out.append((name, cuda_options(setup.cuda)))
        else:
            out.append((name, {}))
    return out


def make_session(
    path: Path, providers: Sequence[str] | ProviderSetup = ("cpu",), intra_op_threads: int = 2,
    dynamic_keypoints: bool = False,
) -> Any:
    """An `onnxruntime.InferenceSession` for `path` with explicit threading and provider options.

    providers: config names, or a `ProviderSetup` with the provider options (`provider_setup`);
    dynamic_keypoints: the model's dynamic axes are keypoint counts (LightGlue): TensorRT gets an
    explicit optimisation profile for 1 .. `profile_max_keypoints` keypoints.
    intra_op_threads: threads of one operator (the CPU cores this session may use);
    inter-op parallelism is off (sequential execution), graph optimisation is ORT_ENABLE_ALL.
    Idle intra-op threads sleep instead of spinning: ORT's default spin-wait keeps each
    session's pool busy after every run, and with several sessions in a row (adaptive
    LightGlue's parts, extractor then matcher) on 2 cores the spinning pools starve the one
    that runs: measured 1024 ms vs 383 ms per adaptive LightGlue pair with 2 threads.
    CPU tensors come from the process-wide arena (`register_shared_cpu_arena`), and ORT's memory
    pattern is off: it pre-plans one more block per input shape beside the arena, resident memory
    that bought no speed on these models.
    The session is recorded for `provider_report`; one that does not run on the first provider
    asked for is logged at WARNING (once per process per provider).
    """
    setup = _as_setup(providers)
    so = ort.SessionOptions()
    so.intra_op_num_threads = int(intra_op_threads)
    so.inter_op_num_threads = 1
    so.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    so.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    so.log_severity_level = 3
    so.enable_mem_pattern = False
    so.add_session_config_entry("session.intra_op.allow_spinning", "0")
    register_shared_cpu_arena()
    so.add_session_config_entry("session.use_env_allocators", "1")
    chosen = session_providers(setup, Path(path), dynamic_keypoints)
    t0 = time.perf_counter()
    sess = ort.InferenceSession(str(path), sess_options=so, providers=chosen)
    build_s = time.perf_counter() - t0
    asked = tuple(PROVIDER_NAMES[p] for p in setup.providers)
    used = str(sess.get_providers()[0])
    report = SessionReport(Path(path).name.split(".")[0], Path(path).name, asked, used, build_s)
    with _lock:
        _sessions.append(report)
    if chosen[0][0] != used:  # available but not taken (e.g. the CUDA/TensorRT libraries failed to load)
        _warn_once(chosen[0][0], f"onnxruntime could not start {chosen[0][0]} for {Path(path).name}: "
                                 f"the models run on {used}")
    return sess
