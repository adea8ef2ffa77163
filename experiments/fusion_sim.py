"""Seeded inputs for fusion experiments and the driver that replays them in arrival order.

* `synthetic_trajectory`: a smooth planar base trajectory of any length (no images).
* `simulate_vloc`: VLoc camera poses at a fixed rate from ground truth, with Gaussian
  noise (per-axis sigmas, body-frame perturbation), a fraction of gross outliers
  (0.5-3 m translation and 10-60 deg rotation errors) and a latency (capture -> arrival)
  drawn uniformly in [latency_min_s, latency_max_s]. All randomness from
  `numpy.random.default_rng(seed)`.
* `run_online`: feeds odometry and VLoc to an `OnlineFusion` in *arrival* order (a VLoc
  result arrives `latency` after its capture time, i.e. after newer odometry), returns
  the fused pose at every odometry message and per-call timings.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from litevloc.base.geometry import interpolate_pose_at, make_T, so3_exp
from litevloc.base.params.fusion import FusionParams
from litevloc.pipelines.fusion.online import OnlineFusion

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]


def synthetic_trajectory(
    duration_s: float, rate_hz: float = 30.0, seed: int = 0, speed: float = 0.5
) -> tuple[I64, F64]:
    """Planar base_link trajectory: a random smooth closed-ish wander at ~`speed` m/s.

    Heading follows the velocity (x forward, z up). Returns (N,) int ns times from 0 and
    (N, 4, 4) `T_world_base`.
    """
    rng = np.random.default_rng(seed)
    n = int(duration_s * rate_hz) + 1
    t = np.arange(n) / rate_hz
    # Sum of a few sinusoids per axis keeps the path bounded (a few metres around 0).
    x = np.zeros(n)
    y = np.zeros(n)
    for _ in range(3):
        f = rng.uniform(0.005, 0.03)
        a = speed / (2 * np.pi * f * 3)
        x += a * np.sin(2 * np.pi * f * t + rng.uniform(0, 2 * np.pi))
        y += a * np.cos(2 * np.pi * f * t + rng.uniform(0, 2 * np.pi))
    yaw = np.unwrap(np.arctan2(np.gradient(y), np.gradient(x)))
    poses = np.stack(
        [
            make_T(so3_exp(np.array([0.0, 0.0, h])), np.array([xi, yi, 0.3]))
            for xi, yi, h in zip(x, y, yaw, strict=True)
        ]
    )
    return np.round(t * 1e9).astype(np.int64), poses


@dataclass(frozen=True)
class VlocSim:
    """Simulated VLoc results: capture and arrival times (int ns), (M,4,4) T_map_camera,
    (M,) bool outlier flags."""

    t_capture_ns: I64
    t_arrival_ns: I64
    T_map_camera: F64
    outlier: NDArray[np.bool_]


def simulate_vloc(
    times_ns: I64,
    T_world_camera: F64,
    rate_hz: float = 1.0,
    sigma_trans: float = 0.05,
    sigma_rot_deg: float = 2.0,
    outlier_ratio: float = 0.1,
    latency_s: tuple[float, float] = (0.1, 1.0),
    seed: int = 0,
) -> VlocSim:
    """VLoc results at `rate_hz` over the ground-truth span (see module docstring)."""
    rng = np.random.default_rng(seed)
    step = round(1e9 / rate_hz)
    tc = np.arange(int(times_ns[0]) + step // 2, int(times_ns[-1]) + 1, step, dtype=np.int64)
    out = np.empty((len(tc), 4, 4))
    flags = rng.random(len(tc)) < outlier_ratio
    for i, t in enumerate(tc):
        T = interpolate_pose_at(int(t), times_ns, T_world_camera)
        if flags[i]:
            d = rng.normal(size=3)
            d *= rng.uniform(0.5, 3.0) / np.linalg.norm(d)
            w = rng.normal(size=3)
            w *= np.radians(rng.uniform(10.0, 60.0)) / np.linalg.norm(w)
        else:
            d = rng.normal(size=3) * sigma_trans
            w = rng.normal(size=3) * np.radians(sigma_rot_deg)
        out[i] = T @ make_T(so3_exp(w), d)
    lat = rng.uniform(latency_s[0], latency_s[1], len(tc))
    return VlocSim(tc, tc + np.round(lat * 1e9).astype(np.int64), out, flags)


@dataclass
class OnlineRun:
    """Result of `run_online`: fused pose per odometry message (NaN before init)."""

    times_ns: I64
    T_map_base: F64
    initialised: NDArray[np.bool_]
    odometry_call_ms: F64  # wall time per add_odometry call
    vloc_call_ms: F64  # wall time per add_vloc call
    odometry_cpu_ms: F64  # thread CPU time per add_odometry call (immune to preemption)
    vloc_cpu_ms: F64
    stats: dict[str, Any]


def run_online(
    params: FusionParams,
    T_base_camera: F64,
    odom_times_ns: I64,
    T_odom_base: F64,
    vloc: VlocSim,
    on_sample: object = None,
) -> OnlineRun:
    """Replay odometry + VLoc in arrival order through a fresh `OnlineFusion`.

    A VLoc result is delivered just before the first odometry message stamped at or after
    its arrival time. `on_sample`, if callable, is called as `on_sample(i, fusion)` after
    odometry message i (for memory/time probes).
    """
    fusion = OnlineFusion(params, T_base_camera)
    n = len(odom_times_ns)
    poses = np.full((n, 4, 4), np.nan)
    init = np.zeros(n, dtype=bool)
    odo_ms = np.empty(n)
    odo_cpu = np.empty(n)
    vloc_ms: list[float] = []
    vloc_cpu: list[float] = []
    order = np.argsort(vloc.t_arrival_ns, kind="stable")
    arr = vloc.t_arrival_ns[order]
    j = 0
    for i in range(n):
        t = int(odom_times_ns[i])
        while j < len(arr) and arr[j] <= t:
            k = order[j]
            c0 = time.thread_time_ns()
            t0 = time.perf_counter()
            fusion.add_vloc(int(vloc.t_capture_ns[k]), vloc.T_map_camera[k])
            vloc_ms.append((time.perf_counter() - t0) * 1e3)
            vloc_cpu.append((time.thread_time_ns() - c0) * 1e-6)
            j += 1
        c0 = time.thread_time_ns()
        t0 = time.perf_counter()
        out = fusion.add_odometry(t, T_odom_base[i])
        odo_ms[i] = (time.perf_counter() - t0) * 1e3
        odo_cpu[i] = (time.thread_time_ns() - c0) * 1e-6
        if out is not None:
            poses[i] = out.T_map_base
            init[i] = True
        if callable(on_sample):
            on_sample(i, fusion)
    return OnlineRun(
        np.asarray(odom_times_ns, dtype=np.int64),
        poses,
        init,
        odo_ms,
        np.array(vloc_ms),
        odo_cpu,
        np.array(vloc_cpu),
        fusion.stats(),
    )
