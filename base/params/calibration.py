"""Colour intrinsics and depth->colour extrinsic of an RGB-D camera (config `rgbd_calibration`;
estimated by `litevloc.pipelines.calibration`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from litevloc.base.geometry import make_T, matrix_to_quat_xyzw, quat_xyzw_to_matrix

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class ColorDepthCalibration:
    """Colour intrinsics (pixels, pinhole) and the depth->colour extrinsic of an RGB-D camera.

    `translation_color_depth` (metres) and `quat_xyzw_color_depth` form `T_color_depth`,
    which maps points from the depth camera's optical frame to the colour camera's.
    """

    # colour focal length along x (pixels)
    color_fx: float
    # colour focal length along y (pixels)
    color_fy: float
    # colour principal point x (pixels)
    color_cx: float
    # colour principal point y (pixels)
    color_cy: float
    # translation of T_color_depth (m)
    translation_color_depth: tuple[float, float, float] = (0.0, 0.0, 0.0)
    # rotation of T_color_depth as a unit quaternion (x, y, z, w)
    quat_xyzw_color_depth: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)
    # cv2.registerDepth: splat each depth point to 2x2 pixels
    depth_dilation: bool = False
    # radial distortion k1 of the colour lens (frames are undistorted to the pinhole K_color)
    color_k1: float = 0.0
    # radial distortion k2 of the colour lens
    color_k2: float = 0.0

    def __post_init__(self) -> None:
        vals = (self.color_fx, self.color_fy, self.color_cx, self.color_cy,
                *self.translation_color_depth, *self.quat_xyzw_color_depth, self.color_k1, self.color_k2)
        if not all(np.isfinite(v) for v in vals):
            raise ValueError("colour calibration values must be finite")
        if self.color_fx <= 0 or self.color_fy <= 0:
            raise ValueError(f"color_fx and color_fy must be > 0, got {self.color_fx}, {self.color_fy}")
        if np.linalg.norm(self.translation_color_depth) > 1.0:
            raise ValueError("translation_color_depth is over 1 m: not a colour/depth pair of one sensor")
        if abs(self.color_k1) > 1.0 or abs(self.color_k2) > 2.0:
            raise ValueError(f"color_k1 / color_k2 ({self.color_k1}, {self.color_k2}) are beyond a "
                             "pinhole-like lens (|k1| <= 1, |k2| <= 2)")
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
class CalibrationParams:
    """Settings of `litevloc calib` (`pipelines.calibration.calibrate_color_depth`; config
    `calibration`). Frame gaps count positions in the selected frames."""

    # pair each frame with the ones this many positions later (wide gaps observe intrinsics best)
    pair_gaps: tuple[int, ...] = (5, 10, 20, 40)
    # frame pairs used at most (evenly spread)
    max_pairs: int = 150
    # SIFT features per image
    sift_features: int = 1500
    # Lowe ratio of the SIFT matches
    ratio: float = 0.75
    # RANSAC threshold of the calibration-free (fundamental matrix) outlier filter (pixels)
    fundamental_px: float = 1.0
    # pairs with fewer matches are skipped
    min_matches: int = 30
    # Huber loss scale of the reprojection residuals (pixels)
    huber_px: float = 1.0
    # residuals above this after a round leave the next round (pixels)
    outlier_px: float = 8.0
    # robust least-squares rounds
    rounds: int = 4
    # depth nearer than this is not lifted (m)
    min_depth_m: float = 0.3
    # depth farther than this is not lifted (m)
    max_depth_m: float = 4.0
    # largest relative spread of the 2x2 depth neighbourhood of a lifted pixel (depth edges)
    edge_rel_tol: float = 0.02
    # pairs whose camera centres are closer than this are skipped (m)
    min_parallax_m: float = 0.02
    # translation of T_color_depth the solve starts from, kept unless estimate_translation (m; Kinect v1)
    translation_prior: tuple[float, float, float] = (-0.025, 0.0, 0.0)
    # also estimate the depth->colour translation (nearly degenerate with the principal point)
    estimate_translation: bool = False
    # also estimate the colour lens's radial distortion k1, k2
    estimate_distortion: bool = False

    def __post_init__(self) -> None:
        if not self.pair_gaps or min(self.pair_gaps) < 1:
            raise ValueError("pair_gaps must be non-empty positive integers")
        if self.max_pairs < 1 or self.rounds < 1 or self.min_matches < 8:
            raise ValueError("max_pairs >= 1, rounds >= 1 and min_matches >= 8 required")
        if not (0 < self.min_depth_m < self.max_depth_m) or self.huber_px <= 0 or self.outlier_px <= 0:
            raise ValueError("need 0 < min_depth_m < max_depth_m and positive huber_px / outlier_px")
