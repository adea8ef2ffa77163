"""The LiteVLoc configuration tree: typed, frozen dataclasses with their defaults.

This is the one place where defaults live. YAML presets in `config/presets/` override
them; `load_config` rejects unknown keys and wrong types, naming the key and file.
Sections own the parameters of one subsystem; pure-algorithm parameter classes are
defined next to their algorithm in `litevloc.pipelines` and referenced here.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from litevloc.hw.oak import CameraConfig
from litevloc.hw.sim.params import SimParams
from litevloc.models.config import ModelsConfig
from litevloc.pipelines.fusion.params import FusionParams
from litevloc.pipelines.localization.vloc import LocalizationParams
from litevloc.pipelines.odometry_drift import DriftParams
from litevloc.pipelines.topomap.build import MappingParams
from numpy.typing import NDArray


@dataclass(frozen=True)
class SourceConfig:
    """Where sensor data come from when no `--source` is given on the command line."""

    kind: Literal["recording", "dataset", "oak-d", "sim"] = "recording"
    path: str = ""
    frames: str = ""  # Python slice over frame indices, as --frames
    strict: bool = False  # live/replay: count and skip bad messages instead of failing

    def __post_init__(self) -> None:
        if self.kind in ("recording", "dataset") and self.frames:
            from litevloc.hw.streams.base import parse_frames

            parse_frames(self.frames)


@dataclass(frozen=True)
class OdometrySimConfig:
    """Simulated proprioceptive odometry for posed datasets that have none."""

    rate_hz: float = 100.0  # 0 = write no odometry
    seed: int = 0
    drift: DriftParams = field(default_factory=DriftParams)

    def __post_init__(self) -> None:
        if not (self.rate_hz >= 0 and self.rate_hz <= 2000):
            raise ValueError(f"rate_hz must be in [0, 2000], got {self.rate_hz}")


@dataclass(frozen=True)
class ReplayConfig:
    """Playback of recordings."""

    rate: float = 1.0  # real-time factor; 0 = as fast as possible

    def __post_init__(self) -> None:
        if not (self.rate >= 0):
            raise ValueError(f"rate must be >= 0, got {self.rate}")


@dataclass(frozen=True)
class FusionConfig:
    """Pose SLAM (VLoc + odometry fusion) and the camera extrinsics it needs.

    `base_camera_*`: pose of the camera optical frame in base_link (`T_base_camera`);
    the default is a camera at the base origin looking along base x (REP-103 body axes),
    as used for datasets where base_link is the camera.
    """

    params: FusionParams = field(default_factory=FusionParams)
    base_camera_translation: tuple[float, float, float] = (0.0, 0.0, 0.0)
    base_camera_quat_xyzw: tuple[float, float, float, float] = (-0.5, 0.5, -0.5, 0.5)

    def __post_init__(self) -> None:
        import math

        vals = (*self.base_camera_translation, *self.base_camera_quat_xyzw)
        if not all(math.isfinite(v) for v in vals):
            raise ValueError("base_camera_translation / base_camera_quat_xyzw must be finite")
        n = math.sqrt(sum(v * v for v in self.base_camera_quat_xyzw))
        if abs(n - 1.0) > 1e-3:
            raise ValueError(
                f"base_camera_quat_xyzw must be a unit quaternion (x, y, z, w), norm is {n:.6f}"
            )

    def T_base_camera(self) -> NDArray[np.float64]:
        """4x4 float64 T_base_camera from the configured translation and quaternion."""
        from litevloc.pipelines.geometry import make_T, quat_xyzw_to_matrix

        return make_T(quat_xyzw_to_matrix(self.base_camera_quat_xyzw), self.base_camera_translation)


@dataclass(frozen=True)
class LiteVLocConfig:
    """Root of the configuration tree."""

    name: str = "default"
    source: SourceConfig = field(default_factory=SourceConfig)
    odometry_sim: OdometrySimConfig = field(default_factory=OdometrySimConfig)
    replay: ReplayConfig = field(default_factory=ReplayConfig)
    camera: CameraConfig = field(default_factory=CameraConfig)  # live OAK-D (source.kind: oak-d)
    models: ModelsConfig = field(default_factory=ModelsConfig)
    mapping: MappingParams = field(default_factory=MappingParams)
    localization: LocalizationParams = field(default_factory=LocalizationParams)
    fusion: FusionConfig = field(default_factory=FusionConfig)
    sim: SimParams = field(default_factory=SimParams)
