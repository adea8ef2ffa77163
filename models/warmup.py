"""Build every onnxruntime session a `models` configuration uses and time it: what
`litevloc models warmup` runs (TensorRT engines built and cached before the first real query)
and what `bench/gpu.py` measures per provider.

Per model: the session(s) are made (`build_s`: TensorRT builds or loads its engines here), each
session runs once at the largest shape of its TensorRT profile (`first_run_s`: LightGlue at
`profile_max_keypoints` per side, so the whole profile's engine exists), then the model's own call
runs `runs` times at its usual shape (`steady_ms`, the median: the extractor and VPR on an image of
their input size, LightGlue on `profile_opt_keypoints` keypoints per side).
"""

from __future__ import annotations

import dataclasses
import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from litevloc.base.params.models import ModelsConfig
from litevloc.models.ort import profile_shape, provider_report, session_reports
from litevloc.models.registry import load_extractor, load_matcher, load_place_recognizer
from litevloc.models.types import Features

ROLES = ("extractor", "second_look", "matcher", "vpr")


@dataclass(frozen=True)
class WarmupResult:
    """One model's warm-up: role (extractor | second_look | matcher | vpr), model id, the providers
    its sessions run on, how many sessions (adaptive LightGlue: 19 parts), whether a provider asked
    for is not in use, and the times (s for building and the first runs, ms for a steady call)."""

    role: str
    model: str
    providers: tuple[str, ...]
    sessions: int
    fell_back: bool
    build_s: float
    first_run_s: float
    steady_ms: float
    runs: int
    shape: str  # what the steady call ran on: "240x320 image", "384 keypoints per side"

    def as_dict(self) -> dict[str, Any]:
        """JSON-able."""
        return {"role": self.role, "model": self.model, "providers": list(self.providers),
                "sessions": self.sessions, "fell_back": self.fell_back, "build_s": round(self.build_s, 4),
                "first_run_s": round(self.first_run_s, 4), "steady_ms": round(self.steady_ms, 3), "runs": self.runs,
                "shape": self.shape}


def model_sessions(model: object) -> list[Any]:
    """The onnxruntime sessions of a model object (`session`, or adaptive LightGlue's encoder, layers and heads)."""
    if hasattr(model, "session"):
        return [model.session]
    if hasattr(model, "encoder"):
        return [model.encoder, *getattr(model, "layers", []), *getattr(model, "heads", [])]
    return []


def _random_input(rng: np.random.Generator, type_name: str, shape: list[int]) -> NDArray[Any]:
    if "int64" in type_name:
        return rng.integers(0, 2, size=shape).astype(np.int64)
    if "float16" in type_name:
        return rng.standard_normal(shape).astype(np.float16)
    return rng.standard_normal(shape).astype(np.float32)


def run_at_max_shape(session: Any, n_keypoints: int, rng: np.random.Generator) -> float:
    """Run `session` once on random inputs with every dynamic axis at `n_keypoints`; seconds."""
    feeds = {i.name: _random_input(rng, str(i.type), profile_shape(list(i.shape), n_keypoints))
             for i in session.get_inputs()}
    t0 = time.perf_counter()
    session.run(None, feeds)
    return time.perf_counter() - t0


def random_features(rng: np.random.Generator, n: int, dim: int, image_wh: tuple[int, int]) -> Features:
    """`n` random keypoints (pixels of an image of `image_wh`) with L2-normalised `dim`-D descriptors."""
    d = rng.standard_normal((n, dim)).astype(np.float32)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    kpts = (rng.random((n, 2)) * np.array(image_wh, np.float32)).astype(np.float32)
    return Features(kpts, d, np.ones(n, np.float32), image_wh)


def _median_ms(call: Callable[[], object], runs: int) -> float:
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        call()
        times.append(1e3 * (time.perf_counter() - t0))
    return statistics.median(times) if times else float("nan")


def warm_up(cfg: ModelsConfig, second_look: bool = True, runs: int = 5, seed: int = 0,
            roles: tuple[str, ...] = ROLES) -> list[WarmupResult]:
    """Build and time every ONNX model `cfg` uses (`roles` of them; the second look's extractor when
    `second_look`); OpenCV extractors and the classical matchers have no session and no row.
    ModelError (naming `litevloc models export`) when a model is missing from the cache."""
    rng = np.random.default_rng(seed)
    h, w = cfg.extractor_size
    image = rng.integers(0, 256, size=(h, w, 3), dtype=np.uint8)
    out: list[WarmupResult] = []

    def one(role: str, load: Callable[[], object], steady: Callable[[Any], object], n_max: int, shape: str) -> None:
        before = len(session_reports())
        t0 = time.perf_counter()
        model = load()
        build_s = time.perf_counter() - t0
        made = session_reports()[before:]
        sessions = model_sessions(model)
        if not sessions or not made:
            return
        first = sum(run_at_max_shape(s, n_max, rng) for s in sessions)
        steady(model)  # its first call at the usual shape (CUDA / TensorRT settle on it), not timed
        report = provider_report(made).models[0]
        out.append(WarmupResult(role, report.model, report.used, len(sessions), report.fell_back, build_s, first,
                                _median_ms(lambda: steady(model), runs), runs, shape))

    aliked = cfg.extractor.startswith("aliked")
    if "extractor" in roles:
        one("extractor", lambda: load_extractor(cfg.extractor, cfg), lambda m: m.extract(image), 1,
            f"{h}x{w} image")
    if "second_look" in roles and second_look and aliked and cfg.second_look_size != cfg.extractor_size:
        full = dataclasses.replace(cfg, extractor_size=cfg.second_look_size, max_keypoints=cfg.second_look_keypoints)
        sh, sw = cfg.second_look_size
        big = rng.integers(0, 256, size=(sh, sw, 3), dtype=np.uint8)
        one("second_look", lambda: load_extractor(cfg.extractor, full), lambda m: m.extract(big), 1,
            f"{sh}x{sw} image")
    if "matcher" in roles:
        n = cfg.profile_opt_keypoints
        pair: list[Features] = []

        def match(m: Any) -> object:
            if not pair:
                dim = int(getattr(m, "input_dim", 128))
                pair.extend(random_features(rng, n, dim, (w, h)) for _ in range(2))
            return m.match(pair[0], pair[1])

        one("matcher", lambda: load_matcher(cfg.matcher, cfg), match, cfg.profile_max_keypoints,
            f"{n} keypoints per side")
    if "vpr" in roles:
        vh, vw = cfg.vpr_size
        one("vpr", lambda: load_place_recognizer(cfg.place_recognizer, cfg), lambda m: m.describe(image),
            1, f"{vh}x{vw} input")
    return out
