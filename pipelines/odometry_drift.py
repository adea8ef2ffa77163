"""A seeded drift model that turns a ground-truth trajectory into "proprioceptive odometry".

Used for datasets that have poses but no odometry (7-Scenes, TUM RGB-D) and by the
simulator. The model, per odometry step k (ground-truth increment `D_k = inv(T_k-1) T_k`
of `base_link`, translation length `d` metres, rotation angle `a` radians):

* translation noise  ~ N(0, (sigma_trans_per_m * d)^2 + sigma_trans_floor^2 * dt) per axis,
* rotation noise     ~ N(0, (sigma_rot_per_m * d + sigma_rot_per_rad * a)^2) per axis
  (a rotation vector applied on the right),
* a constant yaw bias of `yaw_bias_per_m * d` radians about base_link z (up), the
  dominant real-world drift mode (heading error accumulating with distance).

Noisy increments are chained from `T_odom_base = I` at the first sample, so the output
is in its own `odom` frame, as a real robot's odometry is. All randomness comes from
`numpy.random.default_rng(seed)`: the same seed and inputs give the same output.

Default parameters (2 % translation, 1 deg/m rotation noise, 0.5 deg/m yaw bias) are
in the range of legged-robot kinematic odometry.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from litevloc.base.geometry import (
    GeometryError,
    interpolate_pose_at,
    invert,
    make_T,
    rotation_angle,
    so3_exp,
)
from litevloc.base.params.drift import DriftParams


def resample_times(t_start_ns: int, t_end_ns: int, rate_hz: float) -> NDArray[np.int64]:
    """Timestamps from t_start to t_end (inclusive when it falls on the grid) at rate_hz."""
    if rate_hz <= 0:
        raise ValueError(f"odometry rate must be > 0 Hz, got {rate_hz}")
    step = round(1e9 / rate_hz)
    return np.arange(t_start_ns, t_end_ns + 1, step, dtype=np.int64)


def simulate_odometry(
    times_ns: NDArray[np.int64],
    T_world_base: NDArray[np.float64],
    rate_hz: float,
    params: DriftParams,
    seed: int,
) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """Drifting odometry at `rate_hz` from a ground-truth base trajectory.

    Args:
        times_ns: (N,) sorted ground-truth timestamps, int nanoseconds.
        T_world_base: (N, 4, 4) ground-truth poses of base_link.
        rate_hz: output rate; samples are interpolated from the ground truth.
        params: noise model.
        seed: RNG seed.

    Returns:
        (M,) odometry timestamps and (M, 4, 4) `T_odom_base`, starting at identity.
    """
    times = np.asarray(times_ns, dtype=np.int64)
    poses = np.asarray(T_world_base, dtype=np.float64)
    if len(times) < 2:
        raise GeometryError("need at least two ground-truth poses to simulate odometry")
    if np.any(np.diff(times) < 0):
        raise GeometryError("ground-truth timestamps must be sorted")
    out_t = resample_times(int(times[0]), int(times[-1]), rate_hz)
    gt = np.stack([interpolate_pose_at(int(t), times, poses) for t in out_t])
    rng = np.random.default_rng(seed)
    out = np.empty_like(gt)
    out[0] = np.eye(4)
    T = np.eye(4)
    for k in range(1, len(out_t)):
        D = invert(gt[k - 1]) @ gt[k]
        d = float(np.linalg.norm(D[:3, 3]))
        a = rotation_angle(D[:3, :3])
        dt = (out_t[k] - out_t[k - 1]) * 1e-9
        sig_t = np.sqrt((params.sigma_trans_per_m * d) ** 2 + params.sigma_trans_floor**2 * dt)
        sig_r = params.sigma_rot_per_m * d + params.sigma_rot_per_rad * a
        noise_t = rng.normal(0.0, 1.0, 3) * sig_t
        noise_r = rng.normal(0.0, 1.0, 3) * sig_r
        noise_r[2] += params.yaw_bias_per_m * d
        N = make_T(so3_exp(noise_r), noise_t)
        T = T @ D @ N
        out[k] = T
    return out_t, out


class IncrementalDrift:
    """The drift model of `simulate_odometry`, fed one ground-truth increment at a time.

    For closed-loop simulation, where the trajectory is not known in advance. Fed the
    increments `D_k = inv(T_k-1) T_k` of the same resampled ground truth with the same
    seed, it returns exactly the poses `simulate_odometry` returns (tested).
    """

    def __init__(self, params: DriftParams, seed: int) -> None:
        self.params = params
        self.rng = np.random.default_rng(seed)
        self.T_odom_base = np.eye(4)

    def step(self, D: NDArray[np.float64], dt: float) -> NDArray[np.float64]:
        """Apply one ground-truth base_link increment D (4x4) over dt s; returns T_odom_base."""
        p = self.params
        D = np.asarray(D, dtype=np.float64)
        d = float(np.linalg.norm(D[:3, 3]))
        a = rotation_angle(D[:3, :3])
        sig_t = np.sqrt((p.sigma_trans_per_m * d) ** 2 + p.sigma_trans_floor**2 * dt)
        sig_r = p.sigma_rot_per_m * d + p.sigma_rot_per_rad * a
        noise_t = self.rng.normal(0.0, 1.0, 3) * sig_t
        noise_r = self.rng.normal(0.0, 1.0, 3) * sig_r
        noise_r[2] += p.yaw_bias_per_m * d
        self.T_odom_base = self.T_odom_base @ D @ make_T(so3_exp(noise_r), noise_t)
        return self.T_odom_base.copy()
