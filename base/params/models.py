"""Parameters of the model layer (the `models` section of the LiteVLoc config)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

EXTRACTORS = ("aliked-t16", "aliked-n16", "sift", "orb")
MATCHERS = ("lightglue", "lightglue-int8", "lightglue-adaptive", "mnn", "nn-ratio")
PLACE_RECOGNIZERS = ("effnet-gem", "cosplace")
DEFAULT_PLACE_RECOGNIZER = "effnet-gem"


@dataclass(frozen=True)
class ModelsConfig:
    """Which models the runtime uses and how onnxruntime runs them.

    cache_dir: folder of exported ONNX files + manifest.json; "" = `default_cache_dir()`
        ($LITEVLOC_MODEL_CACHE, else $XDG_CACHE_HOME/litevloc/models, else ~/.cache/...).
    providers: onnxruntime execution providers in order of preference; unavailable ones are
        skipped with a log line, CPU is always the last resort.
    intra_op_threads: onnxruntime intra-op threads per session (and OpenCV for SIFT/ORB).
    extractor / extractor_size (h, w) / max_keypoints: local features; ALIKED is exported
        for a fixed (size, top-k); SIFT/ORB also resize to extractor_size.
    matcher ("lightglue-int8": dynamically int8-quantised weights, ~1.5x faster on CPU, same
        epipolar accuracy on the 7-Scenes test pair; "lightglue-adaptive": the reference's
        early stopping + point pruning, `depth_confidence` / `width_confidence`, <= 0 = off),
        match_threshold (LightGlue score), ratio (Lowe ratio for nn-ratio).
    place_recognizer, vpr_size (h, w); cosplace_checkpoint: official CosPlace ResNet-18 / 256
        .pth, only for exporting "cosplace".
    """

    cache_dir: str = ""
    providers: tuple[Literal["cpu", "cuda", "tensorrt"], ...] = ("cpu",)
    intra_op_threads: int = 2
    extractor: Literal["aliked-t16", "aliked-n16", "sift", "orb"] = "aliked-n16"
    extractor_size: tuple[int, int] = (240, 320)
    max_keypoints: int = 512
    # The reference LightGlue's default inference (early stopping + pruning): 1.6x less CPU per
    # LL pair than all 9 layers at the same accuracy on 7-Scenes (bench/matcher.py).
    matcher: Literal["lightglue", "lightglue-int8", "lightglue-adaptive", "mnn", "nn-ratio"] = "lightglue-adaptive"
    match_threshold: float = 0.1
    depth_confidence: float = 0.95
    width_confidence: float = 0.99
    # Match only the strongest N keypoints of each image (0 = all). Extractors return keypoints
    # sorted by score, so this keeps the best; LightGlue's cost grows ~quadratically with N.
    match_max_keypoints: int = 0
    ratio: float = 0.8
    place_recognizer: Literal["effnet-gem", "cosplace"] = "effnet-gem"
    vpr_size: tuple[int, int] = (240, 320)
    cosplace_checkpoint: str = ""

    def __post_init__(self) -> None:
        if not 1 <= self.intra_op_threads <= 64:
            raise ValueError(f"intra_op_threads must be in [1, 64], got {self.intra_op_threads}")
        for key in ("extractor_size", "vpr_size"):
            h, w = getattr(self, key)
            if not (32 <= h <= 4096 and 32 <= w <= 4096):
                raise ValueError(f"{key} must be (h, w) within [32, 4096], got {(h, w)}")
        if not 16 <= self.max_keypoints <= 16384:
            raise ValueError(f"max_keypoints must be in [16, 16384], got {self.max_keypoints}")
        if self.match_max_keypoints < 0:
            raise ValueError(f"match_max_keypoints must be >= 0, got {self.match_max_keypoints}")
        if not 0.0 <= self.match_threshold < 1.0:
            raise ValueError(f"match_threshold must be in [0, 1), got {self.match_threshold}")
        for key in ("depth_confidence", "width_confidence"):
            v = getattr(self, key)
            if not (v <= 0 or 0 < v < 1):
                raise ValueError(f"{key} must be in (0, 1), or <= 0 to disable, got {v}")
        if not 0.0 < self.ratio <= 1.0:
            raise ValueError(f"ratio must be in (0, 1], got {self.ratio}")
        if not self.providers:
            raise ValueError("providers must name at least one provider (e.g. [cpu])")
