"""Parameters of depth from a stereo pair and of frame-to-frame RGB-D odometry (config `stereo`,
`depth_odometry`; the algorithms are `litevloc.pipelines.stereo_depth` and
`litevloc.pipelines.depth_odometry`, both on OpenCV)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

from litevloc.base.settings import Settings, setting


@dataclass(frozen=True)
class SgbmParams(Settings):
    """Semi-global matching (`cv2.StereoSGBM_create`; OpenCV gets `P1 = p1 * channels *
    block_size**2`, P2 the same, the scaling its documentation recommends)."""

    min_disparity: int = setting(0, "smallest disparity searched", unit="px", low=-math.inf)
    num_disparities: int = setting(64, "disparity search range (a multiple of 16)", unit="px", low=1)
    block_size: int = setting(5, "matched block size (odd)", unit="px", low=1, high=11)
    p1: int = setting(8, "SGBM penalty of a disparity change of 1 between neighbours, per channel and block pixel",
                      low=0)
    p2: int = setting(32, "SGBM penalty of larger disparity changes between neighbours, per channel and block "
                      "pixel (above p1)", low=0)
    disp12_max_diff: int = setting(1, "OpenCV's internal left-right check (-1 = off)", unit="px", low=-math.inf)
    uniqueness_ratio: int = setting(
        10, "margin by which the best match must beat the second best", unit="%", low=0, high=100)
    speckle_window_size: int = setting(
        100, "largest speckle region treated as noise (0 = no speckle filter)", unit="px", low=0)
    speckle_range: int = setting(2, "largest disparity variation within a connected region", unit="px", low=0)
    pre_filter_cap: int = setting(63, "truncation of the prefiltered image gradients", low=1, high=63)
    mode: Literal["sgbm", "hh", "sgbm_3way", "hh4"] = setting("sgbm_3way", "OpenCV's SGBM variant")
    lr_max_diff_px: float = setting(1.0, "explicit left-right check against the mirrored match (< 0 = off)",
                                    unit="px", low=-math.inf)

    def check_relations(self) -> None:
        if self.num_disparities % 16:
            raise ValueError(f"num_disparities must be a positive multiple of 16, got {self.num_disparities}")
        if self.block_size % 2 == 0:
            raise ValueError(f"block_size must be odd in [1, 11], got {self.block_size}")
        if not self.p1 < self.p2:
            raise ValueError(f"need 0 <= p1 < p2, got p1={self.p1}, p2={self.p2}")


@dataclass(frozen=True)
class DepthOdometryParams(Settings):
    """Settings passed to `cv2.OdometrySettings` (metres, degrees)."""

    method: Literal["depth", "rgb", "rgbd"] = setting(
        "depth", "what the odometry aligns: depth (ICP), rgb (photometric) or rgbd (both)")
    min_depth: float = setting(0.0, "depth nearer than this is ignored", unit="m", low=0)
    max_depth: float = setting(4.0, "depth farther than this is ignored (above min_depth)", unit="m",
                               low=0, low_open=True)
    max_depth_diff: float = setting(0.07, "ICP correspondence gate between consecutive frames", unit="m",
                                    low=0, low_open=True)
    max_translation: float = setting(0.15, "a step estimated to move farther than this is a failure", unit="m",
                                     low=0, low_open=True)
    max_rotation_deg: float = setting(15.0, "a step estimated to turn more than this is a failure", unit="deg",
                                      low=0, low_open=True)

    def check_relations(self) -> None:
        if self.min_depth >= self.max_depth:
            raise ValueError(f"min_depth ({self.min_depth}) must be < max_depth ({self.max_depth})")
