"""Model registry: finds exported ONNX files in the cache, checks them against the manifest,
and builds extractors / matchers / place recognizers by method name from `ModelsConfig`.

Cache layout: ``<cache>/<model id>.onnx`` and ``<cache>/manifest.json``::

    {"format": 1, "models": {"<id>": {"file": "<id>.onnx", "onnx_sha256": ..., "kind": ...,
     "arch": ..., "input_hw": [h, w] | null, "top_k": k | null, "opset": 19,
     "export_version": 1, "source": {"package": ..., "path": ..., "sha256": ...}, ...}}}

A missing or mismatched model raises `ModelError` naming `litevloc models export`.
No torch here.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

from litevloc.base.errors import LiteVLocError
from litevloc.base.params.models import ModelsConfig
from litevloc.models.catalog import ModelSpec, aliked_id, manifest_fields, spec_for, vpr_id
from litevloc.models.types import FeatureExtractor, Matcher, PlaceRecognizer

if TYPE_CHECKING:
    from litevloc.models.ort import ProviderSetup

MANIFEST = "manifest.json"
MANIFEST_FORMAT = 1


class ModelError(LiteVLocError, RuntimeError):
    """A model is missing from the cache or does not match the manifest / request."""


def default_cache_dir() -> Path:
    """$LITEVLOC_MODEL_CACHE, else $XDG_CACHE_HOME/litevloc/models, else ~/.cache/litevloc/models.

    (The first that is set wins; nothing is created here.)
    """
    env = os.environ.get("LITEVLOC_MODEL_CACHE")
    if env:
        return Path(env).expanduser()
    xdg = os.environ.get("XDG_CACHE_HOME")
    base = Path(xdg).expanduser() if xdg else Path.home() / ".cache"
    return base / "litevloc" / "models"


def cache_dir_of(cfg: ModelsConfig | None) -> Path:
    if cfg is not None and cfg.cache_dir:
        return Path(cfg.cache_dir).expanduser()
    return default_cache_dir()


def sha256_file(path: Path, chunk: int = 1 << 20) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while block := f.read(chunk):
            h.update(block)
    return h.hexdigest()


def read_manifest(cache: Path) -> dict[str, Any]:
    """The manifest's dict ({"format", "models"}); an empty one when the file is absent."""
    p = cache / MANIFEST
    if not p.is_file():
        return {"format": MANIFEST_FORMAT, "models": {}}
    try:
        data = json.loads(p.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise ModelError(
            f"{p}: unreadable model manifest ({exc}); run `litevloc models export --force`"
        ) from exc
    if (
        not isinstance(data, dict)
        or data.get("format") != MANIFEST_FORMAT
        or not isinstance(data.get("models"), dict)
    ):
        raise ModelError(f"{p}: unknown manifest format; run `litevloc models export --force`")
    return data


def write_manifest(cache: Path, data: dict[str, Any]) -> None:
    cache.mkdir(parents=True, exist_ok=True)
    tmp = cache / (MANIFEST + ".tmp")
    tmp.write_text(json.dumps(data, indent=2, sort_keys=True) + "\n")
    tmp.replace(cache / MANIFEST)


def _export_hint(model_id: str, cache: Path) -> str:
    extra = "" if os.environ.get("LITEVLOC_MODEL_CACHE") else f" --cache {cache}"
    return f"run `litevloc models export --model {model_id}{extra}`"


def locate(
    model_id: str, cfg: ModelsConfig | None = None, verify_sha: bool = True
) -> tuple[Path, dict[str, Any]]:
    """Path of the exported model `model_id` and its manifest entry, checked.

    Raises ModelError when the file or its manifest entry is missing, the manifest's export
    version / opset / input size differ from what this code expects, or the file's sha256
    differs from the manifest's (when `verify_sha`).
    """
    spec: ModelSpec = spec_for(model_id)
    cache = cache_dir_of(cfg)
    entry = read_manifest(cache)["models"].get(model_id)
    path = cache / spec.filename
    hint = _export_hint(model_id, cache)
    if entry is None or not path.is_file():
        raise ModelError(f"model {model_id} is not in the model cache {cache}; {hint}")
    for key, want in manifest_fields(spec).items():
        if entry.get(key) != want:
            raise ModelError(
                f"model {model_id} in {cache} was exported with {key}={entry.get(key)!r}, "
                f"this code needs {want!r}; {hint} --force"
            )
    if verify_sha and sha256_file(path) != entry.get("onnx_sha256"):
        raise ModelError(
            f"{path} does not match the sha256 in {cache / MANIFEST} (changed or corrupt); "
            f"{hint} --force"
        )
    if spec.adaptive:
        shas = entry.get("parts_sha256")
        if not isinstance(shas, dict):
            raise ModelError(f"model {model_id} in {cache} has no part checksums; {hint} --force")
        for f in spec.part_files:
            part = cache / f
            if not part.is_file():
                raise ModelError(f"part {f} of model {model_id} is missing from {cache}; {hint} --force")
            if verify_sha and sha256_file(part) != shas.get(f):
                raise ModelError(
                    f"{part} does not match the sha256 in {cache / MANIFEST} (changed or corrupt); {hint} --force"
                )
    return path, entry


def locate_parts(model_id: str, cfg: ModelsConfig | None = None) -> dict[str, Path]:
    """Part name -> checked path of a model exported in parts (adaptive LightGlue)."""
    path, _ = locate(model_id, cfg)
    return {name: path.parent / f for name, f in spec_for(model_id).parts.items()}


def configured_ids(cfg: ModelsConfig) -> list[str]:
    """The ONNX models the configuration needs (extractor, matcher, VPR) or may need (the second
    look's extractor: `localization.second_look.candidates` turns it on, in another section)."""
    ids: list[str] = []
    if cfg.extractor.startswith("aliked"):
        ids.append(aliked_id(cfg.extractor, cfg.extractor_size, cfg.max_keypoints))
        ids.append(aliked_id(cfg.extractor, cfg.second_look_size, cfg.second_look_keypoints))
    if cfg.matcher == "lightglue":
        ids.append("lightglue-aliked")
    elif cfg.matcher == "lightglue-int8":
        ids.append("lightglue-aliked-int8")
    elif cfg.matcher == "lightglue-adaptive":
        ids.append("lightglue-aliked-adaptive")
    if cfg.place_recognizer == "effnet-gem":
        ids.append(vpr_id("effnet-gem", cfg.vpr_size))
    return ids


def _setup(cfg: ModelsConfig) -> ProviderSetup:
    """The providers and provider options of `cfg`'s sessions (TensorRT's caches under its model cache).
    onnxruntime is imported here, where a model is first loaded: the cache's bookkeeping needs none."""
    from litevloc.models.ort import provider_setup

    return provider_setup(cfg, cache_dir_of(cfg))


def load_extractor(name: str, cfg: ModelsConfig | None = None) -> FeatureExtractor:
    """ "aliked-t16" | "aliked-n16" (ONNX, size and top-k from cfg) | "sift" | "orb" (OpenCV)."""
    cfg = cfg or ModelsConfig()
    if name in ("aliked-t16", "aliked-n16"):
        from litevloc.models.aliked import AlikedOnnx

        path, _ = locate(aliked_id(name, cfg.extractor_size, cfg.max_keypoints), cfg)
        return AlikedOnnx(path, name, cfg.extractor_size, _setup(cfg), cfg.intra_op_threads)
    if name in ("sift", "orb"):
        from litevloc.models.classical import OpenCVExtractor

        return OpenCVExtractor(name, cfg.extractor_size, cfg.max_keypoints, cfg.intra_op_threads)
    raise ModelError(
        f"unknown feature extractor {name!r}; known: aliked-t16, aliked-n16, sift, orb"
    )


def check_extractor(name: str, cfg: ModelsConfig | None = None) -> None:
    """ModelError where `load_extractor(name, cfg)` would find its exported model missing or stale;
    nothing is loaded (OpenCV extractors need no file)."""
    cfg = cfg or ModelsConfig()
    if name in ("aliked-t16", "aliked-n16"):
        locate(aliked_id(name, cfg.extractor_size, cfg.max_keypoints), cfg)


def load_matcher(name: str, cfg: ModelsConfig | None = None) -> Matcher:
    """ "lightglue" | "lightglue-int8" (ONNX, for ALIKED-n16, all 9 layers) |
    "lightglue-adaptive" (early stopping + point pruning) | "mnn" (mutual nearest
    neighbour) | "nn-ratio" (nearest neighbour + Lowe ratio test)."""
    cfg = cfg or ModelsConfig()
    if name == "lightglue-adaptive":
        from litevloc.models.lightglue import AdaptiveLightGlueOnnx

        return AdaptiveLightGlueOnnx(
            locate_parts("lightglue-aliked-adaptive", cfg), cfg.match_threshold, cfg.depth_confidence,
            cfg.width_confidence, _setup(cfg), cfg.intra_op_threads,
        )
    if name in ("lightglue", "lightglue-int8"):
        from litevloc.models.lightglue import LightGlueOnnx

        path, _ = locate("lightglue-aliked" + ("-int8" if name == "lightglue-int8" else ""), cfg)
        return LightGlueOnnx(path, cfg.match_threshold, _setup(cfg), cfg.intra_op_threads)
    if name == "mnn":
        from litevloc.models.classical import MutualNNMatcher

        return MutualNNMatcher()
    if name == "nn-ratio":
        from litevloc.models.classical import RatioMatcher

        return RatioMatcher(cfg.ratio)
    raise ModelError(f"unknown matcher {name!r}; known: lightglue, lightglue-int8, lightglue-adaptive, mnn, nn-ratio")


def load_place_recognizer(name: str, cfg: ModelsConfig | None = None) -> PlaceRecognizer:
    """ "effnet-gem" (embedded default) | "cosplace" (needs an exported official checkpoint)."""
    cfg = cfg or ModelsConfig()
    from litevloc.models.vpr import OnnxPlaceRecognizer

    if name == "effnet-gem":
        path, _ = locate(vpr_id("effnet-gem", cfg.vpr_size), cfg)
    elif name == "cosplace":
        try:
            path, _ = locate(vpr_id("cosplace-r18", cfg.vpr_size), cfg)
        except ModelError as exc:
            raise ModelError(
                f"{exc} (CosPlace needs the official checkpoint: add --cosplace-checkpoint PATH)"
            ) from exc
    else:
        raise ModelError(f"unknown place recognizer {name!r}; known: effnet-gem, cosplace")
    return OnnxPlaceRecognizer(
        path,
        name,
        "effnet-gem" if name == "effnet-gem" else "cosplace-r18",
        cfg.vpr_size,
        _setup(cfg),
        cfg.intra_op_threads,
    )
