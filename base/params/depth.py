"""Parameters of depth from a stereo pair and of frame-to-frame RGB-D odometry (config `stereo`,
`depth_odometry`; the algorithms are `litevloc.pipelines.stereo_depth` and
`litevloc.pipelines.depth_odometry`, both on OpenCV)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

SGBM_MODES = ("sgbm", "hh", "sgbm_3way", "hh4")
DEPTH_ODOMETRY_METHODS = ("depth", "rgb", "rgbd")


@dataclass(frozen=True)
class SgbmParams:
    """Semi-global matching (`cv2.StereoSGBM_create`; OpenCV gets `P1 = p1 * channels *
    block_size**2`, P2 the same, the scaling its documentation recommends)."""

    # smallest disparity searched (pixels)
    min_disparity: int = 0
    # disparity search range (pixels, a multiple of 16)
    num_disparities: int = 64
    # matched block size (odd pixels, 1-11)
    block_size: int = 5
    # penalty of a disparity change of 1 between neighbours, per channel and block pixel
    p1: int = 8
    # penalty of larger disparity changes between neighbours, per channel and block pixel
    p2: int = 32
    # OpenCV's internal left-right check (pixels; -1 = off)
    disp12_max_diff: int = 1
    # margin by which the best match must beat the second best (percent)
    uniqueness_ratio: int = 10
    # largest speckle region treated as noise (pixels; 0 = no speckle filter)
    speckle_window_size: int = 100
    # largest disparity variation within a connected region (pixels)
    speckle_range: int = 2
    # truncation of the prefiltered image gradients
    pre_filter_cap: int = 63
    # OpenCV's SGBM variant
    mode: Literal["sgbm", "hh", "sgbm_3way", "hh4"] = "sgbm_3way"
    # explicit left-right check against the mirrored match (pixels; < 0 = off)
    lr_max_diff_px: float = 1.0

    def __post_init__(self) -> None:
        if self.num_disparities <= 0 or self.num_disparities % 16:
            raise ValueError(f"num_disparities must be a positive multiple of 16, got {self.num_disparities}")
        if not (1 <= self.block_size <= 11) or self.block_size % 2 == 0:
            raise ValueError(f"block_size must be odd in [1, 11], got {self.block_size}")
        if not (0 <= self.p1 < self.p2):
            raise ValueError(f"need 0 <= p1 < p2, got p1={self.p1}, p2={self.p2}")
        if not (0 <= self.uniqueness_ratio <= 100):
            raise ValueError(f"uniqueness_ratio must be in [0, 100], got {self.uniqueness_ratio}")
        if self.speckle_window_size < 0 or self.speckle_range < 0:
            raise ValueError("speckle_window_size and speckle_range must be >= 0")
        if not (1 <= self.pre_filter_cap <= 63):
            raise ValueError(f"pre_filter_cap must be in [1, 63], got {self.pre_filter_cap}")
        if self.mode not in SGBM_MODES:
            raise ValueError(f"mode must be one of {sorted(SGBM_MODES)}, got {self.mode!r}")


@dataclass(frozen=True)
class DepthOdometryParams:
    """Settings passed to `cv2.OdometrySettings` (metres, degrees)."""

    # what the odometry aligns: depth (ICP), rgb (photometric) or rgbd (both)
    method: Literal["depth", "rgb", "rgbd"] = "depth"
    # nearer depth is ignored (m)
    min_depth: float = 0.0
    # farther depth is ignored (m)
    max_depth: float = 4.0
    # ICP correspondence gate between consecutive frames (m)
    max_depth_diff: float = 0.07
    # a step estimated to move farther is a failure (m)
    max_translation: float = 0.15
    # a step estimated to turn more is a failure (degrees)
    max_rotation_deg: float = 15.0

    def __post_init__(self) -> None:
        if self.method not in DEPTH_ODOMETRY_METHODS:
            raise ValueError(f"method must be one of {sorted(DEPTH_ODOMETRY_METHODS)}, got {self.method!r}")
        for name in ("max_depth", "max_depth_diff", "max_translation", "max_rotation_deg"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a finite number > 0, got {v}")
        if not (math.isfinite(self.min_depth) and self.min_depth >= 0):
            raise ValueError(f"min_depth must be a finite number >= 0, got {self.min_depth}")
        if self.min_depth >= self.max_depth:
            raise ValueError(f"min_depth ({self.min_depth}) must be < max_depth ({self.max_depth})")
