"""One level floor (`slam.planar.level_floor`): every keyframe's base level and its camera at
one height in the map frame, as absolute factors on the keyframe poses.

The planar edges between consecutive keyframes (`pipelines.slam.planar`) let each step tilt
or climb a little (the gait's bob); a small bias of the visual edges in height or tilt then
adds up over hundreds of steps and the chain climbs or sinks. Where the whole pass is on one
level floor (one storey, no ramps) the bob is the bound for the whole pass, not per step:

* tilt: GTSAM `PoseRotationPrior3D` on the camera rotation at its level version (the base
  turned the least so its z lies along the map's up), with a covariance in the camera frame
  that leaves the rotation about up free (`FREE_SIGMA`) and holds the other two axes to
  `sigma_tilt_rad`;
* height: GTSAM `PoseTranslationPrior3D` on the camera position (map frame, linear in it), free
  across the floor and held along up to the first keyframe's height within `sigma_height_m`.

The level versions are taken from the poses the optimiser starts from; yaw and position
along the floor carry no weight, so they only set where the linearisation starts.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import gtsam
import numpy as np

from litevloc.base.geometry import so3_exp
from litevloc.pipelines.slam.types import F64

FREE_SIGMA = 100.0  # metres and radians on the axes a level floor leaves free


@dataclass(frozen=True, eq=False)
class LevelFloor:
    """The floor of the pass: `up` (3,) unit vector in the map frame, the camera mount
    `T_base_camera` (4x4), the first keyframe's camera height along `up` (m, map frame), and
    the bob the base keeps within (sigmas, metres and radians)."""

    up: F64
    T_base_camera: F64
    height_m: float
    sigma_height_m: float
    sigma_tilt_rad: float


def level_rotation(R_map_camera: F64, floor: LevelFloor) -> F64:
    """The camera rotation (3x3) with its base turned the least so that base z lies along up."""
    R_bc = np.asarray(floor.T_base_camera, np.float64)[:3, :3]
    R_base = R_map_camera @ R_bc.T
    z = R_base[:, 2]
    axis = np.cross(z, floor.up)
    s, c = float(np.linalg.norm(axis)), float(z @ floor.up)
    R_fix = np.eye(3) if s < 1e-12 else so3_exp(axis / s * np.arctan2(s, c))
    return np.asarray(R_fix @ R_base @ R_bc, np.float64)


def level_factors(floor: LevelFloor, keys_poses: Iterable[tuple[int, F64]]) -> gtsam.NonlinearFactorGraph:
    """Two factors per (GTSAM key, 4x4 T_map_camera the optimiser starts from): see the module docstring."""
    u = np.asarray(floor.up, np.float64)
    uu = np.outer(u, u)
    trans_cov = FREE_SIGMA**2 * (np.eye(3) - uu) + floor.sigma_height_m**2 * uu
    trans_noise = gtsam.noiseModel.Gaussian.Covariance(trans_cov)
    graph = gtsam.NonlinearFactorGraph()
    for key, T in keys_poses:
        R = level_rotation(np.asarray(T, np.float64)[:3, :3], floor)
        n = R.T @ u  # up in the camera frame: rotation about it is free
        nn = np.outer(n, n)
        rot_cov = FREE_SIGMA**2 * nn + floor.sigma_tilt_rad**2 * (np.eye(3) - nn)
        p = np.asarray(T, np.float64)[:3, 3]
        p = p + u * (floor.height_m - float(p @ u))
        prior = gtsam.Pose3(gtsam.Rot3(R), p)
        graph.add(gtsam.PoseRotationPrior3D(key, prior, gtsam.noiseModel.Gaussian.Covariance(rot_cov)))
        graph.add(gtsam.PoseTranslationPrior3D(key, prior, trans_noise))
    return graph


def floor_of(T_map_first: F64, T_base_camera: F64, up: tuple[float, float, float], sigma_height_m: float,
             sigma_tilt_rad: float) -> LevelFloor:
    """The level floor of a pass whose first keyframe's camera is at `T_map_first` (map frame)."""
    u = np.asarray(up, np.float64) / np.linalg.norm(up)
    return LevelFloor(u, np.asarray(T_base_camera, np.float64), float(np.asarray(T_map_first)[:3, 3] @ u),
                      sigma_height_m, sigma_tilt_rad)
