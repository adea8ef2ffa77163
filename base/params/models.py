"""Parameters of the model layer (the `models` section of the LiteVLoc config)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

EXTRACTORS = ("aliked-t16", "aliked-n16", "sift", "orb")
MATCHERS = ("lightglue", "lightglue-int8", "lightglue-adaptive", "mnn", "nn-ratio")
PLACE_RECOGNIZERS = ("effnet-gem", "cosplace")
DEFAULT_PLACE_RECOGNIZER = "effnet-gem"


MIB = 1 << 20  # bytes


@dataclass(frozen=True)
class TensorrtConfig:
    """onnxruntime's TensorRT execution provider (config `models.tensorrt`), used when `models.providers`
    names `tensorrt`. Engines and the timing cache are kept under the model cache by default, so each
    engine is built once (`litevloc models warmup` builds them ahead of the first run)."""

    # GPU the TensorRT engines run on (CUDA device index; onnxruntime's `device_id`)
    device_id: int = 0
    # build FP16 engines where the GPU supports them (`trt_fp16_enable`; off = FP32, slower)
    fp16: bool = True
    # keep built engines on disk and reuse them at the next start (`trt_engine_cache_enable`)
    engine_cache: bool = True
    # folder of the engine cache; "" = `trt-engines` in the model cache folder (`trt_engine_cache_path`)
    engine_cache_dir: str = ""
    # keep TensorRT's layer timing cache on disk: later builds are faster (`trt_timing_cache_enable`)
    timing_cache: bool = True
    # folder of the timing cache; "" = `trt-timing` in the model cache folder (`trt_timing_cache_path`)
    timing_cache_dir: str = ""
    # TensorRT builder workspace limit (MiB; `trt_max_workspace_size` is this in bytes)
    max_workspace_mib: int = 1024
    # largest keypoint count the LightGlue engines take (0 = max of max_keypoints and second_look_keypoints)
    profile_max_keypoints: int = 0

    def __post_init__(self) -> None:
        if not 0 <= self.device_id <= 63:
            raise ValueError(f"tensorrt.device_id must be in [0, 63], got {self.device_id}")
        if not 16 <= self.max_workspace_mib <= 1 << 20:
            raise ValueError(f"tensorrt.max_workspace_mib must be in [16, 1048576] MiB, got {self.max_workspace_mib}")
        if not (self.profile_max_keypoints == 0 or 16 <= self.profile_max_keypoints <= 16384):
            raise ValueError(
                f"tensorrt.profile_max_keypoints must be 0 (from the models section) or in [16, 16384], "
                f"got {self.profile_max_keypoints}"
            )


@dataclass(frozen=True)
class CudaConfig:
    """onnxruntime's CUDA execution provider (config `models.cuda`), used when `models.providers` names
    `cuda` (and for the nodes TensorRT does not take when both are named)."""

    # GPU the CUDA sessions run on (CUDA device index; onnxruntime's `device_id`)
    device_id: int = 0
    # how cuDNN picks convolution algorithms (`cudnn_conv_algo_search`; HEURISTIC: quick start, less memory)
    cudnn_conv_algo_search: Literal["EXHAUSTIVE", "HEURISTIC", "DEFAULT"] = "HEURISTIC"
    # how the CUDA memory arena grows (`arena_extend_strategy`; kSameAsRequested suits a shared-memory Jetson)
    arena_extend_strategy: Literal["kNextPowerOfTwo", "kSameAsRequested"] = "kSameAsRequested"
    # cap of the CUDA memory arena per session (MiB, `gpu_mem_limit` in bytes; 0 = no cap)
    gpu_mem_limit_mib: int = 0

    def __post_init__(self) -> None:
        if not 0 <= self.device_id <= 63:
            raise ValueError(f"cuda.device_id must be in [0, 63], got {self.device_id}")
        if not 0 <= self.gpu_mem_limit_mib <= 1 << 20:
            raise ValueError(f"cuda.gpu_mem_limit_mib must be in [0, 1048576] MiB, got {self.gpu_mem_limit_mib}")


@dataclass(frozen=True)
class ModelsConfig:
    """Which models the runtime uses and how onnxruntime runs them (config `models`).

    ALIKED is exported for a fixed (extractor_size, max_keypoints); SIFT/ORB also resize to
    extractor_size. Sizes are (height, width) in pixels.
    """

    # folder of exported ONNX files + manifest.json; "" = $LITEVLOC_MODEL_CACHE, else ~/.cache/litevloc/models
    cache_dir: str = ""
    # onnxruntime execution providers in order of preference (one missing: a WARNING and skipped; CPU is last)
    providers: tuple[Literal["cpu", "cuda", "tensorrt"], ...] = ("cpu",)
    # TensorRT provider options (engine and timing caches, FP16, workspace, LightGlue's shape profile)
    tensorrt: TensorrtConfig = field(default_factory=TensorrtConfig)
    # CUDA provider options (device, cuDNN algorithm search, memory arena)
    cuda: CudaConfig = field(default_factory=CudaConfig)
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
    # the second look (localization.second_look.candidates): extractor input size (h, w pixels) ...
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

    @property
    def profile_max_keypoints(self) -> int:
        """The largest keypoint count LightGlue is given: `tensorrt.profile_max_keypoints`, else the
        larger of `max_keypoints` and `second_look_keypoints` (the second look matches all of them)."""
        return self.tensorrt.profile_max_keypoints or max(self.max_keypoints, self.second_look_keypoints)

    @property
    def profile_opt_keypoints(self) -> int:
        """The keypoint count LightGlue usually gets (TensorRT tunes its kernels for it): the first look's
        `match_max_keypoints` of `max_keypoints` (all of them when 0), within the profile's maximum."""
        n = self.max_keypoints if self.match_max_keypoints <= 0 else min(self.match_max_keypoints, self.max_keypoints)
        return min(n, self.profile_max_keypoints)
