"""Colour intrinsics and depth->colour extrinsic of an RGB-D camera (config `rgbd_calibration`;
estimated by `litevloc.pipelines.calibration`)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from litevloc.base.geometry import make_T, matrix_to_quat_xyzw, quat_xyzw_to_matrix
from litevloc.base.settings import Settings, setting

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class ColorDepthCalibration(Settings):
    """Colour intrinsics (pixels, pinhole) and the depth->colour extrinsic of an RGB-D camera.

    `translation_color_depth` (metres) and `quat_xyzw_color_depth` form `T_color_depth`,
    which maps points from the depth camera's optical frame to the colour camera's.
    """

    color_fx: float = setting(description="colour focal length along x", unit="px", low=0, low_open=True)
    color_fy: float = setting(description="colour focal length along y", unit="px", low=0, low_open=True)
    color_cx: float = setting(description="colour principal point along x", unit="px", low=-math.inf)
    color_cy: float = setting(description="colour principal point along y", unit="px", low=-math.inf)
    translation_color_depth: tuple[float, float, float] = setting(
        (0.0, 0.0, 0.0), "translation of T_color_depth, the depth optical frame in the colour one (at most 1 m long)",
        unit="m", low=-1, high=1)
    quat_xyzw_color_depth: tuple[float, float, float, float] = setting(
        (0.0, 0.0, 0.0, 1.0), "rotation of T_color_depth as a unit quaternion (x, y, z, w)", low=-math.inf)
    depth_dilation: bool = setting(False, "cv2.registerDepth splats each depth point to 2x2 pixels")
    color_k1: float = setting(
        0.0, "radial distortion k1 of the colour lens (frames are undistorted to the pinhole K_color)", low=-1, high=1)
    color_k2: float = setting(
        0.0, "radial distortion k2 of the colour lens (frames are undistorted to the pinhole K_color)", low=-2, high=2)

    def check_relations(self) -> None:
        if np.linalg.norm(self.translation_color_depth) > 1.0:
            raise ValueError("translation_color_depth is over 1 m: not a colour/depth pair of one sensor")
        n = float(np.linalg.norm(self.quat_xyzw_color_depth))
        if abs(n - 1.0) > 1e-3:
            raise ValueError(f"quat_xyzw_color_depth must be a unit quaternion (x, y, z, w), norm is {n:.6f}")

    def K_color(self) -> F64:
        """3x3 float64 colour intrinsics."""
        return np.array([[self.color_fx, 0.0, self.color_cx], [0.0, self.color_fy, self.color_cy], [0.0, 0.0, 1.0]])

    def T_color_depth(self) -> F64:
        """4x4 float64 transform from the depth to the colour optical frame."""
        R = quat_xyzw_to_matrix(np.asarray(self.quat_xyzw_color_depth))
        return make_T(R, np.asarray(self.translation_color_depth))

    @staticmethod
    def from_arrays(
        K_color: NDArray[np.floating], T_color_depth: NDArray[np.floating], k1_k2: tuple[float, float] = (0.0, 0.0),
    ) -> ColorDepthCalibration:
        K = np.asarray(K_color, dtype=np.float64)
        T = np.asarray(T_color_depth, dtype=np.float64)
        q = matrix_to_quat_xyzw(T[:3, :3])
        return ColorDepthCalibration(float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]),
                                     (float(T[0, 3]), float(T[1, 3]), float(T[2, 3])),
                                     (float(q[0]), float(q[1]), float(q[2]), float(q[3])),
                                     color_k1=float(k1_k2[0]), color_k2=float(k1_k2[1]))


@dataclass(frozen=True)
class CalibrationParams(Settings):
    """Settings of `litevloc calib` (`pipelines.calibration.calibrate_color_depth`; config
    `calibration`). Frame gaps count positions in the selected frames."""

    pair_gaps: tuple[int, ...] = setting(
        (5, 10, 20, 40), "pair each frame with the ones this many positions later (wide gaps observe intrinsics best)",
        low=1)
    max_pairs: int = setting(150, "frame pairs used at most, spread evenly over the frames", low=1)
    sift_features: int = setting(1500, "SIFT features per image", low=-math.inf)
    ratio: float = setting(0.75, "Lowe ratio of the SIFT matches", low=-math.inf)
    fundamental_px: float = setting(
        1.0, "RANSAC threshold of the calibration-free (fundamental matrix) outlier filter", unit="px", low=-math.inf)
    min_matches: int = setting(30, "frame pairs with fewer SIFT matches than this are skipped", low=8)
    huber_px: float = setting(1.0, "Huber loss scale of the reprojection residuals", unit="px", low=0, low_open=True)
    outlier_px: float = setting(
        8.0, "residuals above this after a round leave the next round", unit="px", low=0, low_open=True)
    rounds: int = setting(4, "robust least-squares rounds", low=1)
    min_depth_m: float = setting(0.3, "depth nearer than this is not lifted", unit="m", low=0, low_open=True)
    max_depth_m: float = setting(
        4.0, "depth farther than this is not lifted (above min_depth_m)", unit="m", low=0, low_open=True)
    edge_rel_tol: float = setting(
        0.02, "largest relative spread of the 2x2 depth neighbourhood of a lifted pixel (depth edges)", low=-math.inf)
    min_parallax_m: float = setting(
        0.02, "pairs whose camera centres are closer than this are skipped", unit="m", low=-math.inf)
    translation_prior: tuple[float, float, float] = setting(
        (-0.025, 0.0, 0.0), "translation of T_color_depth the solve starts from, kept unless estimate_translation "
        "(Kinect v1)", unit="m", low=-math.inf)
    estimate_translation: bool = setting(
        False, "also estimate the depth->colour translation (nearly degenerate with the principal point)")
    estimate_distortion: bool = setting(False, "also estimate the colour lens's radial distortion k1, k2")

    def check_relations(self) -> None:
        if not self.pair_gaps:
            raise ValueError("pair_gaps must be non-empty positive integers")
        if not self.min_depth_m < self.max_depth_m:
            raise ValueError(f"need 0 < min_depth_m < max_depth_m, got {self.min_depth_m}, {self.max_depth_m}")
