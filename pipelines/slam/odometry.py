"""The robot's odometry for the pose graph: trustworthy segments and the noise of an edge.

`OdometryTrack` keeps the `T_odom_base` samples in time order, split into segments where
the odometry cannot be trusted across: a silence longer than `max_gap_s` (the robot may
have moved unobserved, the driver may have restarted) and a jump (a step faster than the
robot can move: a reset or a fault). Poses are interpolated within a segment only, so no
edge ever spans a gap or a jump; each split is recorded as a `Fault`.

`odometry_edge` turns the odometry between two keyframes into a camera-to-camera edge with
the configured per-metre noise, rotated into the camera frame through the extrinsic.
"""

from __future__ import annotations

import bisect

import gtsam
import numpy as np

from litevloc.base.geometry import interpolate_pose, invert, rotation_angle
from litevloc.base.params.slam import SlamOdometryParams
from litevloc.pipelines.slam.types import F64, Fault


class OdometryTrack:
    """Odometry samples split into segments at gaps and jumps (see the module docstring)."""

    def __init__(self, params: SlamOdometryParams) -> None:
        self.params = params
        self._t: list[list[int]] = []
        self._T: list[list[F64]] = []
        self.faults: list[Fault] = []
        self.samples = 0
        self.out_of_order = 0  # samples not after the previous one (dropped)

    @property
    def segments(self) -> int:
        return len(self._t)

    @property
    def last_t_ns(self) -> int | None:
        return self._t[-1][-1] if self._t else None

    def add(self, t_ns: int, T_odom_base: F64) -> None:
        """Append one sample (stamps must increase; others are counted and dropped)."""
        T = np.asarray(T_odom_base, np.float64)
        self.samples += 1
        if not self._t:
            self._start(t_ns, T)
            return
        t0, T0 = self._t[-1][-1], self._T[-1][-1]
        if t_ns <= t0:
            self.out_of_order += 1
            return
        dt = (t_ns - t0) * 1e-9
        p = self.params
        if dt > p.max_gap_s:
            self.faults.append(Fault("odometry gap", t0 * 1e-9, f"no odometry for {dt:.2f} s (> {p.max_gap_s:g})",
                                     "no odometry edge spans it"))
            self._start(t_ns, T)
            return
        D = invert(T0) @ T
        d, a = float(np.linalg.norm(D[:3, 3])), float(np.degrees(rotation_angle(D[:3, :3])))
        if d > p.max_speed_mps * dt or a > p.max_turn_dps * dt:
            self.faults.append(Fault("odometry jump", t_ns * 1e-9,
                                     f"odometry moved {d:.2f} m / {a:.1f} deg in {dt * 1e3:.0f} ms "
                                     f"(> {p.max_speed_mps:g} m/s or {p.max_turn_dps:g} deg/s)",
                                     "no odometry edge spans it"))
            self._start(t_ns, T)
            return
        self._t[-1].append(int(t_ns))
        self._T[-1].append(T)

    def _start(self, t_ns: int, T: F64) -> None:
        self._t.append([int(t_ns)])
        self._T.append([T])

    def pose_at(self, t_ns: int) -> tuple[int, F64] | None:
        """(segment, T_odom_base) interpolated at `t_ns`, or None when no segment covers it."""
        for s in range(len(self._t) - 1, -1, -1):
            ts = self._t[s]
            if ts[0] <= t_ns <= ts[-1]:
                k = bisect.bisect_left(ts, t_ns)
                if ts[k] == t_ns:
                    return s, self._T[s][k]
                frac = (t_ns - ts[k - 1]) / (ts[k] - ts[k - 1])
                return s, interpolate_pose(self._T[s][k - 1], self._T[s][k], frac)
            if ts[-1] < t_ns:
                return None
        return None

    def covers_until(self, t_ns: int) -> bool:
        """Whether a sample at or after `t_ns` has arrived (a frame at `t_ns` can be posed now)."""
        return bool(self._t) and self._t[-1][-1] >= t_ns


def adjoint(T: F64) -> F64:
    """6x6 adjoint of a pose in GTSAM's tangent order (rotation, translation)."""
    return np.asarray(gtsam.Pose3(gtsam.Rot3(T[:3, :3]), T[:3, 3].astype(float)).AdjointMap(), np.float64)


def odometry_edge(T_odom_base_a: F64, T_odom_base_b: F64, T_base_camera: F64,
                  params: SlamOdometryParams) -> tuple[F64, F64]:
    """Camera-to-camera motion `T_ca_cb` between two odometry poses of base_link and its 6x6
    covariance (GTSAM order, see `pipelines.slam.types`): per axis, translation sigma
    sqrt((k_t d)^2 + floor^2) and rotation sigma k_r d + k_a a (+ floor) for d metres travelled
    and a radians turned, in base_link, then moved into the camera frame."""
    D = invert(T_odom_base_a) @ T_odom_base_b
    d = float(np.linalg.norm(D[:3, 3]))
    a = rotation_angle(D[:3, :3])
    p = params
    s_t = float(np.hypot(p.sigma_m_per_m * d, p.sigma_floor_m))
    s_r = float(np.hypot(np.radians(p.sigma_deg_per_m) * d + p.sigma_deg_per_deg * a, np.radians(p.sigma_floor_deg)))
    cov_base = np.diag([s_r**2] * 3 + [s_t**2] * 3)
    T_cb = invert(T_base_camera)
    Ad = adjoint(T_cb)
    return T_cb @ D @ T_base_camera, Ad @ cov_base @ Ad.T
