"""Parameters of the model layer (the `models` section of the LiteVLoc config)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

from litevloc.base.settings import Settings, section, setting

EXTRACTORS = ("aliked-t16", "aliked-n16", "sift", "orb")
MATCHERS = ("lightglue", "lightglue-int8", "lightglue-adaptive", "mnn", "nn-ratio")
PLACE_RECOGNIZERS = ("effnet-gem", "cosplace")
DEFAULT_PLACE_RECOGNIZER = "effnet-gem"


MIB = 1 << 20  # bytes


@dataclass(frozen=True)
class TensorrtConfig(Settings):
    """onnxruntime's TensorRT execution provider (config `models.tensorrt`), used when `models.providers`
    names `tensorrt`. Engines and the timing cache are kept under the model cache by default, so each
    engine is built once (`litevloc models warmup` builds them ahead of the first run)."""

    device_id: int = setting(
        0, "GPU the TensorRT engines run on (CUDA device index; onnxruntime's `device_id`)", low=0, high=63)
    fp16: bool = setting(True, "build FP16 engines where the GPU supports them (`trt_fp16_enable`; off = FP32, slower)")
    engine_cache: bool = setting(
        True, "keep built engines on disk and reuse them at the next start (`trt_engine_cache_enable`)")
    engine_cache_dir: str = setting(
        "", "folder of the engine cache; \"\" = `trt-engines` in the model cache folder (`trt_engine_cache_path`)")
    timing_cache: bool = setting(
        True, "keep TensorRT's layer timing cache on disk: later builds are faster (`trt_timing_cache_enable`)")
    timing_cache_dir: str = setting(
        "", "folder of the timing cache; \"\" = `trt-timing` in the model cache folder (`trt_timing_cache_path`)")
    max_workspace_mib: int = setting(
        1024, "TensorRT builder workspace limit (`trt_max_workspace_size` is this in bytes)", unit="MiB", low=16,
        high=1 << 20)
    profile_max_keypoints: int = setting(
        0, "largest keypoint count the LightGlue engines take (0 = max of max_keypoints and second_look_keypoints)",
        low=16, high=16384, off=0)


@dataclass(frozen=True)
class CudaConfig(Settings):
    """onnxruntime's CUDA execution provider (config `models.cuda`), used when `models.providers` names
    `cuda` (and for the nodes TensorRT does not take when both are named)."""

    device_id: int = setting(
        0, "GPU the CUDA sessions run on (CUDA device index; onnxruntime's `device_id`)", low=0, high=63)
    cudnn_conv_algo_search: Literal["EXHAUSTIVE", "HEURISTIC", "DEFAULT"] = setting(
        "HEURISTIC", "how cuDNN picks convolution algorithms (`cudnn_conv_algo_search`; HEURISTIC: quick start, less "
        "memory)")
    arena_extend_strategy: Literal["kNextPowerOfTwo", "kSameAsRequested"] = setting(
        "kSameAsRequested", "how the CUDA memory arena grows (`arena_extend_strategy`; kSameAsRequested suits a "
        "shared-memory Jetson)")
    gpu_mem_limit_mib: int = setting(
        0, "cap of the CUDA memory arena per session (`gpu_mem_limit` in bytes; 0 = no cap)", low=0, high=1 << 20,
        unit="MiB")


@dataclass(frozen=True)
class ModelsConfig(Settings):
    """Which models the runtime uses and how onnxruntime runs them (config `models`).

    ALIKED is exported for a fixed (extractor_size, max_keypoints); SIFT/ORB also resize to
    extractor_size. Sizes are (height, width) in pixels.
    """

    cache_dir: str = setting(
        "", 'folder of exported ONNX files + manifest.json; "" = $LITEVLOC_MODEL_CACHE, else ~/.cache/litevloc/models')
    providers: tuple[Literal["cpu", "cuda", "tensorrt"], ...] = setting(
        ("cpu",), "onnxruntime execution providers in order of preference (one missing: a WARNING and skipped; CPU is "
        "last)")
    tensorrt: TensorrtConfig = section(
        TensorrtConfig, "TensorRT provider options (engine and timing caches, FP16, workspace, LightGlue's shape "
        "profile)")
    cuda: CudaConfig = section(CudaConfig, "CUDA provider options (device, cuDNN algorithm search, memory arena)")
    intra_op_threads: int = setting(
        2, "onnxruntime intra-op threads per session (and OpenCV's for SIFT/ORB) in offline commands", low=1, high=64)
    extractor: Literal["aliked-t16", "aliked-n16", "sift", "orb"] = setting("aliked-n16", "local feature extractor")
    extractor_size: tuple[int, int] = setting((240, 320), "extractor input size (h, w)", unit="px", low=32, high=4096)
    max_keypoints: int = setting(512, "keypoints extracted per image", low=16, high=16384)
    matcher: Literal["lightglue", "lightglue-int8", "lightglue-adaptive", "mnn", "nn-ratio"] = setting(
        "lightglue-adaptive", "matcher; lightglue-adaptive: the reference's early stopping + point pruning")
    second_look_size: tuple[int, int] = setting(
        (480, 640), "extractor input size (h, w) of the second look (localization.second_look.candidates)", unit="px",
        low=32, high=4096)
    second_look_keypoints: int = setting(
        2048, "keypoints per image of the second look, for the query and the keyframes' stored images",
        low=16, high=16384)
    second_look_match_keypoints: int = setting(
        1024, "the second look matches only the strongest N of its keypoints per image (LightGlue's cost grows about "
        "as N squared; 0 = all)", low=0)
    match_threshold: float = setting(0.1, "LightGlue match score threshold", low=0, high=1, high_open=True)
    depth_confidence: float = setting(
        0.95, "lightglue-adaptive: early-stopping confidence (<= 0 = off)", low=-math.inf, high=1, high_open=True)
    width_confidence: float = setting(
        0.99, "lightglue-adaptive: point-pruning confidence (<= 0 = off)", low=-math.inf, high=1, high_open=True)
    match_max_keypoints: int = setting(384, "match only the strongest N keypoints of each image (0 = all)", low=0)
    ratio: float = setting(0.8, "Lowe ratio of the nn-ratio matcher", low=0, low_open=True, high=1)
    place_recognizer: Literal["effnet-gem", "cosplace"] = setting("effnet-gem", "place recognition (VPR) model")
    vpr_size: tuple[int, int] = setting((240, 320), "VPR input size (h, w)", unit="px", low=32, high=4096)
    cosplace_checkpoint: str = setting("", "official CosPlace ResNet-18/256 .pth, only for exporting 'cosplace'")

    def check_relations(self) -> None:
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
