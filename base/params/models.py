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
    """Which models the runtime uses and how onnxruntime runs them (config `models`).

    ALIKED is exported for a fixed (extractor_size, max_keypoints); SIFT/ORB also resize to
    extractor_size. Sizes are (height, width) in pixels.
    """

    # folder of exported ONNX files + manifest.json; "" = $LITEVLOC_MODEL_CACHE, else ~/.cache/litevloc/models
    cache_dir: str = ""
    # onnxruntime execution providers in order of preference (unavailable ones are skipped; CPU is last)
    providers: tuple[Literal["cpu", "cuda", "tensorrt"], ...] = ("cpu",)
    # onnxruntime intra-op threads per session (and OpenCV's for SIFT/ORB) in offline commands
    intra_op_threads: int = 2
    # local feature extractor
    extractor: Literal["aliked-t16", "aliked-n16", "sift", "orb"] = "aliked-n16"
    # extractor input size (h, w pixels)
    extractor_size: tuple[int, int] = (240, 320)
    # keypoints extracted per image
    max_keypoints: int = 512
    # matcher; lightglue-adaptive: the reference's early stopping + point pruning
    matcher: Literal["lightglue", "lightglue-int8", "lightglue-adaptive", "mnn", "nn-ratio"] = "lightglue-adaptive"
    # the second look (localization.second_look_candidates): extractor input size (h, w pixels) ...
    second_look_size: tuple[int, int] = (480, 640)
    # ... and keypoints per image, for the query and the keyframes' stored images (all matched)
    second_look_keypoints: int = 2048
    # LightGlue match score threshold
    match_threshold: float = 0.1
    # lightglue-adaptive: early-stopping confidence (<= 0 = off)
    depth_confidence: float = 0.95
    # lightglue-adaptive: point-pruning confidence (<= 0 = off)
    width_confidence: float = 0.99
    # match only the strongest N keypoints of each image (0 = all)
    match_max_keypoints: int = 384
    # Lowe ratio of the nn-ratio matcher
    ratio: float = 0.8
    # place recognition (VPR) model
    place_recognizer: Literal["effnet-gem", "cosplace"] = "effnet-gem"
    # VPR input size (h, w pixels)
    vpr_size: tuple[int, int] = (240, 320)
    # official CosPlace ResNet-18/256 .pth, only for exporting "cosplace"
    cosplace_checkpoint: str = ""

    def __post_init__(self) -> None:
        if not 1 <= self.intra_op_threads <= 64:
            raise ValueError(f"intra_op_threads must be in [1, 64], got {self.intra_op_threads}")
        for key in ("extractor_size", "vpr_size", "second_look_size"):
            h, w = getattr(self, key)
            if not (32 <= h <= 4096 and 32 <= w <= 4096):
                raise ValueError(f"{key} must be (h, w) within [32, 4096], got {(h, w)}")
        for key in ("max_keypoints", "second_look_keypoints"):
            if not 16 <= getattr(self, key) <= 16384:
                raise ValueError(f"{key} must be in [16, 16384], got {getattr(self, key)}")
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
