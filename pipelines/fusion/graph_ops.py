"""Small pieces of `OnlineFusion`'s pose graph: input validation, rigid-transform shortcuts, the
smoother's estimate of one state, and the VLoc noise model.

Poses are 4x4 float64 (`T_a_b` maps points from b to a); covariances here are 6x6 in GTSAM order
(rotation first) unless a name says ROS.
"""

from __future__ import annotations

import math

import gtsam
import numpy as np
from numpy.typing import NDArray

from litevloc.base.params.fusion import FusionParams

F64 = NDArray[np.float64]

I3 = np.eye(3)
ROW3 = np.array([0.0, 0.0, 0.0, 1.0])


def valid_pose(T: NDArray[np.floating]) -> F64 | None:
    """T as a float64 4x4 rigid transform (rotation re-orthonormalised if off by > 1e-9),
    or None if it is not finite / not rigid within 1e-4."""
    A = np.asarray(T, dtype=np.float64)
    if A.shape != (4, 4) or not np.isfinite(A).all():
        return None
    R = A[:3, :3]
    err = float(np.abs(R @ R.T - I3).max())
    if err > 1e-4 or np.linalg.det(R) < 0 or float(np.abs(A[3] - ROW3).max()) > 1e-6:
        return None
    out = A.copy()
    if err > 1e-9:  # remove round-off so GTSAM gets an exact rotation
        U, _, Vt = np.linalg.svd(R)
        out[:3, :3] = U @ Vt
    return out


def inv(T: F64) -> F64:
    """Inverse of one 4x4 rigid transform (cheaper than geometry.invert for a single one)."""
    out = np.eye(4)
    Rt = T[:3, :3].T
    out[:3, :3] = Rt
    out[:3, 3] = -Rt @ T[:3, 3]
    return out


def angle(R: F64) -> float:
    """Rotation angle (rad) from the trace; accurate enough for noise models and thresholds."""
    return math.acos(max(-1.0, min(1.0, (R[0, 0] + R[1, 1] + R[2, 2] - 1.0) * 0.5)))


def valid_cov(C: NDArray[np.floating] | None) -> F64 | None:
    """C symmetrised, None for None; ValueError unless it is a finite positive-definite 6x6."""
    if C is None:
        return None
    A = np.asarray(C, dtype=np.float64)
    if A.shape != (6, 6) or not np.all(np.isfinite(A)):
        raise ValueError("covariance must be a finite 6x6 matrix")
    A = 0.5 * (A + A.T)
    if np.linalg.eigvalsh(A).min() <= 0:
        raise ValueError("covariance must be positive definite")
    return A


def estimate_pose3(smoother: gtsam.IncrementalFixedLagSmoother, key: int) -> gtsam.Pose3:
    """The smoother's current estimate of the pose at `key` (T_map_base).

    gtsam 4.3a1, the only gtsam wheel for Python 3.10 on aarch64 (JetPack 6), does not wrap
    `calculateEstimatePose3`; there the whole window's estimate is computed (~40 us for 300 states).
    """
    one_key = getattr(smoother, "calculateEstimatePose3", None)
    if one_key is not None:
        pose: gtsam.Pose3 = one_key(key)
        return pose
    every_key: gtsam.Pose3 = smoother.calculateEstimate().atPose3(key)
    return every_key


def pose3(T: F64) -> gtsam.Pose3:
    return gtsam.Pose3(T)


def vloc_noise_model(cov_gtsam: F64, params: FusionParams) -> gtsam.noiseModel.Base:
    """Noise model of a VLoc prior: Gaussian with the 6x6 covariance `cov_gtsam` (GTSAM order:
    rotation first), behind the robust kernel `params.robust_kernel` (none, huber, cauchy)."""
    gauss = gtsam.noiseModel.Gaussian.Covariance(cov_gtsam)
    if params.robust_kernel == "huber":
        return gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(params.robust_k), gauss)
    if params.robust_kernel == "cauchy":
        return gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Cauchy.Create(params.robust_k), gauss)
    return gauss


def odom_cov(params: FusionParams, T_a: F64, T_b: F64) -> F64:
    """Odometry-model noise (GTSAM order) of the increment from `T_a` to `T_b` (T_odom_base)."""
    D = inv(T_a) @ T_b
    s = params.odom_sigmas(math.sqrt(float(D[:3, 3] @ D[:3, 3])), angle(D[:3, :3]))
    return np.diag(s**2)


def carried_cov(params: FusionParams, D: F64, path: tuple[float, float] | None) -> F64:
    """Noise (GTSAM order) of the odometry `D` that carries a VLoc pose from its capture time to
    its keyframe's: the odometry model over the larger of the net motion and, for a late pose,
    the `path` (m, rad) driven since its capture (a pose carried through a turn on the spot, or
    out and back, is as uncertain as the turn or the drive made it)."""
    net_m, net_rad = math.sqrt(float(D[:3, 3] @ D[:3, 3])), angle(D[:3, :3])
    path_m, path_rad = path if path is not None else (0.0, 0.0)
    return np.diag(params.odom_sigmas(max(net_m, path_m), max(net_rad, path_rad)) ** 2)
