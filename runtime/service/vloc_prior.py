"""The VLoc prior at a frame's stamp: the fused map->odom correction applied to the odometry
interpolated at `t_frame`, with the age of the information it rests on.

The fusion thread records every odometry pose it fuses (`OdometryHistory.add`); the VLoc
thread asks for the prior of the frame it is about to localize (`prior_at`). A frame taken
by VLoc is older than the newest odometry (the camera pipeline and VLoc's own latency),
so the latest fused pose would put the prior where the robot is *now*, not where it was
when the frame was captured; and its age is the time since the last VLoc fix the fused
pose rests on, not 0.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from litevloc.base.geometry import camera_position_covariance, interpolate_pose_at
from litevloc.pipelines.localization.search_region import SearchRegion

F64 = NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class VlocPrior:
    """`T_map_camera` (4x4, metres) at the frame's stamp; `age_s`: seconds from the last VLoc
    fix fusion accepted to the frame's stamp (0 if the frame is older than that fix);
    `travel_m`: the odometry's path length over that time (metres; None where the history does
    not cover it: the fix older than the history, or the frame outside it);
    `interpolated`: False where the stamp lay outside the odometry history and the nearest
    odometry pose was used (the age then includes the gap); `region`: an initial pose's bound on
    the next global localization (then `T_map_camera` is the initial pose's camera pose, not a fix);
    `cov_position`: 3x3 covariance of the camera's position (m^2, map frame) from fusion's latest
    covariance (newer than the frame: it only overstates), None where fusion gave none."""

    T_map_camera: F64
    age_s: float
    interpolated: bool = True
    travel_m: float | None = None
    region: SearchRegion | None = None
    cov_position: F64 | None = None


class OdometryHistory:
    """The last `capacity` (t_ns, T_odom_base) odometry poses with the odometer (base_link's
    path length since the first pose, metres), thread-safe (one writer, any readers)."""

    def __init__(self, capacity: int = 4000) -> None:
        if capacity < 2:
            raise ValueError("capacity must be >= 2")
        self._t = np.zeros(capacity, np.int64)
        self._T = np.zeros((capacity, 4, 4))
        self._odometer = np.zeros(capacity)
        self._n = 0  # poses written in total
        self._lock = threading.Lock()

    def add(self, t_ns: int, T_odom_base: NDArray[np.floating]) -> None:
        """Append a pose; one not newer than the last is ignored (time must increase)."""
        with self._lock:
            cap = len(self._t)
            last = (self._n - 1) % cap
            if self._n and t_ns <= self._t[last]:
                return
            T = np.asarray(T_odom_base, np.float64)
            step = float(np.linalg.norm(T[:3, 3] - self._T[last, :3, 3])) if self._n else 0.0
            self._odometer[self._n % cap] = self._odometer[last] + step
            self._t[self._n % cap] = t_ns
            self._T[self._n % cap] = T
            self._n += 1

    def _snapshot(self, values: NDArray[np.floating]) -> tuple[NDArray[np.int64], NDArray[np.floating]]:
        """(stamps, `values` — the poses or the odometer) of the kept poses, oldest first (copies)."""
        with self._lock:
            n, cap = self._n, len(self._t)
            order = np.arange(n - min(n, cap), n) % cap
            return self._t[order].copy(), values[order].copy()

    def __len__(self) -> int:
        return min(self._n, len(self._t))

    def at(self, t_ns: int) -> tuple[F64, int] | None:
        """(T_odom_base at `t_ns`, stamp used): interpolated inside the history; outside it,
        the nearest end's pose and stamp. None while empty."""
        times, poses = self._snapshot(self._T)
        if len(times) == 0:
            return None
        if t_ns <= times[0]:
            return poses[0], int(times[0])
        if t_ns >= times[-1]:
            return poses[-1], int(times[-1])
        k = int(np.searchsorted(times, t_ns))
        return interpolate_pose_at(t_ns, times[k - 1 : k + 1], poses[k - 1 : k + 1]), t_ns

    def travel(self, t0_ns: int, t1_ns: int) -> float | None:
        """base_link's path length from `t0_ns` to `t1_ns` (metres, >= 0; linear between
        samples); None where either stamp lies outside the history (the path there is unknown)."""
        times, odometer = self._snapshot(self._odometer)
        lo, hi = min(t0_ns, t1_ns), max(t0_ns, t1_ns)
        if len(times) == 0 or lo < times[0] or hi > times[-1]:
            return None
        at = np.interp([lo, hi], times.astype(np.float64), odometer)
        return float(at[1] - at[0])


def prior_at(
    t_frame_ns: int, T_map_odom: NDArray[np.floating], history: OdometryHistory, T_base_camera: NDArray[np.floating],
    last_fix_ns: int | None, cov_base_ros: NDArray[np.floating] | None = None,
) -> VlocPrior | None:
    """`T_map_odom @ T_odom_base(t_frame) @ T_base_camera` and its age (see `VlocPrior`);
    None without odometry. `last_fix_ns`: stamp of the last VLoc result fusion accepted
    (None: unknown, counted as 0). `cov_base_ros`: fusion's 6x6 covariance of `T_map_base`
    (ROS order, body frame), carried to the camera's position at the frame's stamp."""
    got = history.at(t_frame_ns)
    if got is None:
        return None
    T_odom_base, t_used = got
    T_map_base = np.asarray(T_map_odom, np.float64) @ T_odom_base
    T = T_map_base @ np.asarray(T_base_camera, np.float64)
    since = 0 if last_fix_ns is None else t_frame_ns - last_fix_ns
    gap = abs(t_frame_ns - t_used)
    travel = None if last_fix_ns is None else (0.0 if since <= 0 else history.travel(last_fix_ns, t_frame_ns))
    cov = None if cov_base_ros is None else camera_position_covariance(T_map_base, cov_base_ros, T_base_camera)
    return VlocPrior(T, max(since, 0) * 1e-9 + gap * 1e-9, interpolated=gap == 0, travel_m=travel, cov_position=cov)
