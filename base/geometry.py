"""SE(3) and pinhole-camera geometry on numpy arrays.

Conventions used across LiteVLoc:

* `T_a_b` is a 4x4 float64 homogeneous matrix that maps points expressed in frame `b`
  to frame `a`: `p_a = T_a_b @ p_b`. Hence `T_a_c = T_a_b @ T_b_c` and
  `T_b_a = inv(T_a_b)`.
* Frames: `map`, `odom`, `base_link`, `camera` (optical: x right, y down, z forward).
* Quaternions are stored **x, y, z, w** (ROS / TUM order), unit norm, w >= 0 on output.
* Lengths in metres, angles in radians unless a name says `_deg`, times in int
  nanoseconds (`t_ns`).
* Depth images are HxW float32 metres with NaN marking invalid pixels.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from litevloc.base.errors import LiteVLocError

F64 = NDArray[np.float64]


class GeometryError(LiteVLocError, ValueError):
    """Invalid geometric input (not a rigid transform, bad shapes, NaN...)."""


def make_T(R: NDArray[np.floating], t: NDArray[np.floating]) -> F64:
    """Build a 4x4 transform from a 3x3 rotation and a 3-vector translation."""
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = np.asarray(t, dtype=np.float64).reshape(3)
    return T


def invert(T_a_b: NDArray[np.floating]) -> F64:
    """Inverse of a rigid transform (or a stack ...x4x4): returns `T_b_a`."""
    T = np.asarray(T_a_b, dtype=np.float64)
    R = T[..., :3, :3]
    t = T[..., :3, 3]
    Rt = np.swapaxes(R, -1, -2)
    out = np.zeros_like(T)
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", Rt, t)
    out[..., 3, 3] = 1.0
    return out


def compose(*transforms: NDArray[np.floating]) -> F64:
    """Chain transforms left to right: compose(T_a_b, T_b_c) = T_a_c."""
    if not transforms:
        return np.eye(4)
    out = np.asarray(transforms[0], dtype=np.float64)
    for T in transforms[1:]:
        out = out @ np.asarray(T, dtype=np.float64)
    return out


def transform_points(T_a_b: NDArray[np.floating], points_b: NDArray[np.floating]) -> F64:
    """Map Nx3 points from frame b to frame a."""
    P = np.asarray(points_b, dtype=np.float64)
    return P @ np.asarray(T_a_b)[:3, :3].T + np.asarray(T_a_b)[:3, 3]


def is_rigid(T: NDArray[np.floating], atol: float = 1e-6) -> bool:
    """True if T is a finite 4x4 proper rigid transform."""
    T = np.asarray(T)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        return False
    R = T[:3, :3]
    return bool(
        np.allclose(R @ R.T, np.eye(3), atol=atol)
        and abs(np.linalg.det(R) - 1.0) < atol * 10
        and np.allclose(T[3], [0, 0, 0, 1], atol=atol)
    )


def check_rigid(T: NDArray[np.floating], name: str = "transform", atol: float = 1e-5) -> F64:
    """Return T as float64 or raise GeometryError naming `name` if it is not rigid."""
    out: F64 = np.asarray(T, dtype=np.float64)
    if not is_rigid(out, atol=atol):
        raise GeometryError(f"{name} is not a finite 4x4 rigid transform: {out.tolist()}")
    return out


def project_to_so3(R: NDArray[np.floating]) -> F64:
    """Nearest rotation matrix (SVD), e.g. to clean up matrices read from text files."""
    U, _, Vt = np.linalg.svd(np.asarray(R, dtype=np.float64))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return np.asarray(U @ D @ Vt, dtype=np.float64)


def quat_xyzw_to_matrix(q_xyzw: NDArray[np.floating]) -> F64:
    """Unit quaternion (x, y, z, w) -> 3x3 rotation. Normalises; rejects zero norm."""
    q = np.asarray(q_xyzw, dtype=np.float64).reshape(4)
    n = np.linalg.norm(q)
    if not np.isfinite(n) or n < 1e-12:
        raise GeometryError(f"quaternion {q.tolist()} has zero or invalid norm")
    x, y, z, w = q / n
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def matrix_to_quat_xyzw(R: NDArray[np.floating]) -> F64:
    """3x3 rotation -> unit quaternion (x, y, z, w) with w >= 0 (Shepperd's method)."""
    R = np.asarray(R, dtype=np.float64)
    tr = np.trace(R)
    if tr > 0:
        s = 2.0 * np.sqrt(tr + 1.0)
        w, x, y, z = 0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        s = 2.0 * np.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2])
        w, x, y, z = (R[2, 1] - R[1, 2]) / s, 0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s
    elif R[1, 1] > R[2, 2]:
        s = 2.0 * np.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2])
        w, x, y, z = (R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s
    else:
        s = 2.0 * np.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1])
        w, x, y, z = (R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s
    # the norm summed in this fixed order (not a BLAS dot): the same bits on every CPU, and as
    # `hw.ros_msgs.odometry_cdr` packs them
    q: F64 = np.array([x, y, z, w], dtype=np.float64) / float(np.sqrt(x * x + y * y + z * z + w * w))
    return -q if q[3] < 0 else q


def so3_exp(omega: NDArray[np.floating]) -> F64:
    """Rotation vector (axis * angle, radians) -> 3x3 rotation (Rodrigues)."""
    w = np.asarray(omega, dtype=np.float64).reshape(3)
    theta = float(np.linalg.norm(w))
    K = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
    if theta < 1e-8:
        return np.asarray(np.eye(3) + K + 0.5 * K @ K, dtype=np.float64)
    return np.asarray(np.eye(3) + np.sin(theta) / theta * K + (1 - np.cos(theta)) / theta**2 * K @ K,
                      dtype=np.float64)


def so3_log(R: NDArray[np.floating]) -> F64:
    """3x3 rotation -> rotation vector (radians), robust near 0 and pi."""
    q = matrix_to_quat_xyzw(R)
    v, w = q[:3], q[3]
    s = float(np.linalg.norm(v))
    if s < 1e-12:
        return 2.0 * v
    angle = 2.0 * np.arctan2(s, w)
    return np.asarray(v / s * angle, dtype=np.float64)


def rotation_angle(R: NDArray[np.floating]) -> float:
    """Angle (radians, in [0, pi]) of a rotation matrix."""
    return float(np.linalg.norm(so3_log(R)))


def relative_pose_error(T_a: NDArray[np.floating], T_b: NDArray[np.floating]) -> tuple[float, float]:
    """Translation (m) and rotation (deg) difference between two poses of the same frame."""
    D = invert(T_a) @ np.asarray(T_b, dtype=np.float64)
    return float(np.linalg.norm(np.asarray(T_a)[:3, 3] - np.asarray(T_b)[:3, 3])), float(
        np.degrees(rotation_angle(D[:3, :3]))
    )


# 6x6 pose covariances: ROS order (tx, ty, tz, rx, ry, rz) <-> GTSAM Pose3 order (rx, ry, rz,
# tx, ty, tz). Swapping the two 3-blocks is its own inverse.
_SWAP_TRANS_ROT = np.array([3, 4, 5, 0, 1, 2])


def gtsam_to_ros_covariance(cov: NDArray[np.floating]) -> F64:
    """6x6 covariance in GTSAM Pose3 order (rot, trans) -> ROS order (trans, rot)."""
    c = np.asarray(cov, dtype=np.float64).reshape(6, 6)
    return np.asarray(c[np.ix_(_SWAP_TRANS_ROT, _SWAP_TRANS_ROT)], dtype=np.float64)


def ros_to_gtsam_covariance(cov: NDArray[np.floating]) -> F64:
    """6x6 covariance in ROS order (trans, rot) -> GTSAM Pose3 order (rot, trans)."""
    return gtsam_to_ros_covariance(cov)


def camera_position_covariance(
    T_map_base: NDArray[np.floating], cov_ros: NDArray[np.floating], T_base_camera: NDArray[np.floating]
) -> F64:
    """3x3 covariance (m^2, map frame) of the camera's position `T_map_base @ T_base_camera`,
    from the 6x6 covariance of `T_map_base` in ROS order (trans, rot) of a body-frame (right)
    perturbation, as GTSAM's Pose3 marginals are: the rotation's part reaches the camera over
    the lever arm base -> camera."""
    T = np.asarray(T_map_base, dtype=np.float64)
    C = np.asarray(cov_ros, dtype=np.float64).reshape(6, 6)
    x, y, z = np.asarray(T_base_camera, dtype=np.float64)[:3, 3]
    skew = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    # T exp((v, w)) moves the camera by R (v + w x t_bc) = R (v - [t_bc]x w)
    J = T[:3, :3] @ np.hstack([np.eye(3), -skew])
    return np.asarray(J @ C @ J.T, dtype=np.float64)


def slerp_xyzw(q0: NDArray[np.floating], q1: NDArray[np.floating], s: float) -> F64:
    """Spherical linear interpolation between unit quaternions, s in [0, 1]."""
    a = np.asarray(q0, dtype=np.float64)
    b = np.asarray(q1, dtype=np.float64)
    d = float(np.dot(a, b))
    if d < 0.0:
        b, d = -b, -d
    if d > 0.9995:
        q = a + s * (b - a)
        return np.asarray(q / np.linalg.norm(q), dtype=np.float64)
    theta = np.arccos(np.clip(d, -1.0, 1.0))
    q = (np.sin((1 - s) * theta) * a + np.sin(s * theta) * b) / np.sin(theta)
    return np.asarray(q / np.linalg.norm(q), dtype=np.float64)


def interpolate_pose(T0: NDArray[np.floating], T1: NDArray[np.floating], s: float) -> F64:
    """Pose between T0 (s=0) and T1 (s=1): slerp on rotation, linear on translation."""
    q = slerp_xyzw(matrix_to_quat_xyzw(np.asarray(T0)[:3, :3]), matrix_to_quat_xyzw(np.asarray(T1)[:3, :3]), s)
    t = (1 - s) * np.asarray(T0)[:3, 3] + s * np.asarray(T1)[:3, 3]
    return make_T(quat_xyzw_to_matrix(q), t)


def interpolate_pose_at(t_ns: int, times_ns: NDArray[np.int64], poses: NDArray[np.floating]) -> F64:
    """Pose at time `t_ns` from a time-sorted trajectory (N,) times and (N,4,4) poses.

    Interpolates between the two bracketing samples; raises GeometryError outside
    [times[0], times[-1]] (no extrapolation: callers decide what to do there).
    """
    times = np.asarray(times_ns, dtype=np.int64)
    if times.ndim != 1 or len(times) == 0 or len(times) != len(poses):
        raise GeometryError("times and poses must be non-empty and of equal length")
    if t_ns < times[0] or t_ns > times[-1]:
        raise GeometryError(f"t_ns={t_ns} outside trajectory [{times[0]}, {times[-1]}]")
    i = int(np.searchsorted(times, t_ns, side="right"))
    if i >= len(times):
        return np.asarray(poses[-1], dtype=np.float64).copy()
    i0 = max(i - 1, 0)
    t0, t1 = int(times[i0]), int(times[i])
    s = 0.0 if t1 == t0 else (t_ns - t0) / (t1 - t0)
    return interpolate_pose(poses[i0], poses[i], s)


@dataclass(frozen=True)
class PinholeIntrinsics:
    """Pinhole camera without distortion; pixel (u, v) = (fx x/z + cx, fy y/z + cy).

    Pixel centres are at integer coordinates (OpenCV convention).
    """

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    def __post_init__(self) -> None:
        vals = (self.fx, self.fy, self.cx, self.cy)
        if not all(np.isfinite(v) for v in vals) or self.fx <= 0 or self.fy <= 0:
            raise GeometryError(f"invalid intrinsics {vals}")
        if self.width <= 0 or self.height <= 0:
            raise GeometryError(f"invalid image size {self.width}x{self.height}")

    @property
    def K(self) -> F64:
        """3x3 camera matrix."""
        return np.array([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1.0]])

    @classmethod
    def from_K(cls, K: NDArray[np.floating], width: int, height: int) -> PinholeIntrinsics:
        K = np.asarray(K, dtype=np.float64)
        if K.shape != (3, 3):
            raise GeometryError(f"K must be 3x3, got {K.shape}")
        return cls(float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]), int(width), int(height))

    def scaled(self, width: int, height: int) -> PinholeIntrinsics:
        """Intrinsics for the same camera resized to width x height (pixel-centre aware)."""
        sx, sy = width / self.width, height / self.height
        return PinholeIntrinsics(
            self.fx * sx, self.fy * sy, (self.cx + 0.5) * sx - 0.5, (self.cy + 0.5) * sy - 0.5, width, height
        )


def project(K: NDArray[np.floating], points_cam: NDArray[np.floating]) -> F64:
    """Project Nx3 camera-frame points to Nx2 pixels (no visibility check)."""
    P = np.asarray(points_cam, dtype=np.float64)
    uvw = P @ np.asarray(K, dtype=np.float64).T
    return uvw[:, :2] / uvw[:, 2:3]


def pixels_in_view(T_cam_world: NDArray[np.floating], points_world: NDArray[np.floating], K: NDArray[np.floating],
                   shape: tuple[int, ...], min_z: float = 0.1) -> tuple[F64, NDArray[np.int64], NDArray[np.int64]]:
    """The Nx3 world points that land in an image of `shape` (h, w, ...) seen from `T_cam_world`,
    at least `min_z` metres ahead: their (M, 3) camera-frame points and rounded pixel (col, row)."""
    T = np.asarray(T_cam_world, dtype=np.float64)
    P = np.asarray(points_world, dtype=np.float64).reshape(-1, 3) @ T[:3, :3].T + T[:3, 3]
    P = P[P[:, 2] > min_z]
    uv = project(K, P)
    col, row = np.round(uv[:, 0]).astype(np.int64), np.round(uv[:, 1]).astype(np.int64)
    h, w = shape[:2]
    inside = (col >= 0) & (col < w) & (row >= 0) & (row < h)
    return P[inside], col[inside], row[inside]


def backproject_pixels(K: NDArray[np.floating], uv: NDArray[np.floating], z: NDArray[np.floating]) -> F64:
    """Lift Nx2 pixels with depths z (N,) metres to Nx3 camera-frame points."""
    K = np.asarray(K, dtype=np.float64)
    uv = np.asarray(uv, dtype=np.float64)
    z = np.asarray(z, dtype=np.float64)
    x = (uv[:, 0] - K[0, 2]) / K[0, 0] * z
    y = (uv[:, 1] - K[1, 2]) / K[1, 1] * z
    return np.stack([x, y, z], axis=1)


def backproject_depth(
    depth: NDArray[np.floating], K: NDArray[np.floating], stride: int = 1
) -> tuple[F64, NDArray[np.intp]]:
    """Lift every valid pixel of an HxW depth image (metres, NaN/<=0 invalid).

    Returns (Nx3 camera-frame points, Nx2 integer pixel coordinates (u, v)); `stride`
    subsamples the grid.
    """
    d = np.asarray(depth)
    if d.ndim != 2:
        raise GeometryError(f"depth must be HxW, got shape {d.shape}")
    vs, us = np.mgrid[0 : d.shape[0] : stride, 0 : d.shape[1] : stride]
    z = d[vs, us].astype(np.float64)
    valid = np.isfinite(z) & (z > 0)
    uv = np.stack([us[valid], vs[valid]], axis=1)
    return backproject_pixels(K, uv, z[valid]), uv


def undistort_normalized(xd: NDArray[np.floating], k1: float, k2: float) -> F64:
    """Undo radial distortion on normalised image coordinates (OpenCV `undistortPoints`).

    xd: (N, 2) distorted normalised coordinates ((u - cx) / fx, (v - cy) / fy). Returns the
    (N, 2) undistorted ones x with xd = x (1 + k1 r^2 + k2 r^4), r = |x|.
    """
    import cv2

    xd64: F64 = np.asarray(xd, dtype=np.float64).reshape(-1, 2)
    if k1 == 0.0 and k2 == 0.0:
        return xd64.copy()
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 1e-12)
    eye = np.eye(3)
    out = cv2.undistortPoints(xd64.reshape(-1, 1, 2), eye, np.array([k1, k2, 0.0, 0.0, 0.0]),
                              R=eye, P=eye, criteria=criteria)
    return np.asarray(out, dtype=np.float64).reshape(-1, 2)


def register_depth(
    depth: NDArray[np.floating], K_depth: NDArray[np.floating], K_color: NDArray[np.floating],
    T_color_depth: NDArray[np.floating], size_wh: tuple[int, int], dilation: bool = False,
) -> NDArray[np.float32]:
    """Re-project an HxW depth image (metres, NaN/<=0 invalid) of the depth camera into
    the colour camera (OpenCV `registerDepth`, no colour distortion).

    Returns an (h, w) float32 image of colour-camera z in metres, NaN where no depth lands
    (nearest surface wins where several do). `T_color_depth` maps depth- to colour-frame points.
    """
    import cv2

    d = np.asarray(depth, dtype=np.float32)
    d = np.where(np.isfinite(d) & (d > 0), d, np.float32(0.0)).astype(np.float32)
    out = cv2.registerDepth(
        np.asarray(K_depth, dtype=np.float64), np.asarray(K_color, dtype=np.float64), np.zeros(5),
        np.asarray(T_color_depth, dtype=np.float64), d, (int(size_wh[0]), int(size_wh[1])), depthDilation=dilation,
    )
    res: NDArray[np.float32] = np.asarray(out, dtype=np.float32)
    res[~(res > 0)] = np.nan
    return res
