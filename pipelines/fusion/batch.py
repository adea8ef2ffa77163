"""Batch refinement of a whole session (the paper's PS-Opt) with Levenberg-Marquardt.

Same factors as `OnlineFusion`: states at keyframes decimated from odometry (same
`keyframe_*` rules) **plus a state at every VLoc capture time** (odometry interpolated
there), BetweenFactorPose3 from odometry increments, a PriorFactorPose3 per VLoc pose
(camera -> base with `T_base_camera`), the configured robust kernel. Gating, offline:
after a first LM solve, priors whose squared Mahalanobis residual against the solution
exceeds `gate_chi2` are dropped and LM runs again (repeated until none is dropped, at
most 3 times). Initial values: odometry mapped by the `T_map_odom` that most VLoc
results agree with (a consensus vote, so an outlier cannot seed the solution).

Output: `T_map_base` at every odometry time (the preceding state composed with the
odometry increment since it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import gtsam
import numpy as np
from numpy.typing import NDArray

from litevloc.base.geometry import interpolate_pose_at, invert, ros_to_gtsam_covariance, rotation_angle
from litevloc.base.params.fusion import FusionParams
from litevloc.pipelines.fusion.graph_ops import valid_pose, vloc_noise_model

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]


@dataclass(frozen=True)
class BatchInfo:
    """Diagnostics of one `refine_session` run."""

    states: int
    priors_used: int
    priors_gated: int
    priors_outside: int  # VLoc results outside the odometry time span (ignored)
    iterations: int


def _keyframes(times: I64, T_odom: F64, p: FusionParams) -> list[int]:
    keep = [0]
    for i in range(1, len(times)):
        D = invert(T_odom[keep[-1]]) @ T_odom[i]
        if (
            times[i] - times[keep[-1]] >= p.keyframe_period_s * 1e9
            or np.linalg.norm(D[:3, 3]) >= p.keyframe_dist_m
            or rotation_angle(D[:3, :3]) >= math.radians(p.keyframe_angle_deg)
        ):
            keep.append(i)
    if keep[-1] != len(times) - 1:
        keep.append(len(times) - 1)
    return keep


def _consensus_map_odom(T_map_odom: F64, p: FusionParams) -> F64:
    best, best_n = 0, -1
    for i in range(len(T_map_odom)):
        n = 0
        for j in range(len(T_map_odom)):
            D = invert(T_map_odom[i]) @ T_map_odom[j]
            if np.linalg.norm(
                T_map_odom[i][:3, 3] - T_map_odom[j][:3, 3]
            ) <= p.init_max_trans_m and rotation_angle(D[:3, :3]) <= math.radians(
                p.init_max_rot_deg
            ):
                n += 1
        if n > best_n:
            best, best_n = i, n
    return np.asarray(T_map_odom[best], dtype=np.float64)


@dataclass(frozen=True)
class BatchResult:
    """`refine_session` output: (N,) times, (N, 4, 4) T_map_base, diagnostics."""

    times_ns: I64
    T_map_base: F64
    info: BatchInfo


def _odometry_chain(st_T: F64, T_map_odom0: F64,
                    params: FusionParams) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
    """The odometry between consecutive states ((S, 4, 4) T_odom_base) as GTSAM between factors,
    and the initial values: each state moved into the map by `T_map_odom0`."""
    base = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    for k in range(len(st_T)):
        values.insert(k, gtsam.Pose3(T_map_odom0 @ st_T[k]))
        if k > 0:
            D = invert(st_T[k - 1]) @ st_T[k]
            s = params.odom_sigmas(float(np.linalg.norm(D[:3, 3])), rotation_angle(D[:3, :3]))
            base.add(
                gtsam.BetweenFactorPose3(
                    k - 1, k, gtsam.Pose3(D), gtsam.noiseModel.Diagonal.Sigmas(s)
                )
            )
    return base, values


def _prior_mahalanobis2(result: gtsam.Values, vl_state: NDArray[np.int64], vl_T_mb: F64, covs: list[F64]) -> F64:
    """Squared Mahalanobis distance of each VLoc prior (T_map_base, GTSAM-order covariance) from
    its state in `result` (gtsam.Values)."""
    return np.array(
        [
            float(
                np.sum(
                    np.square(
                        np.linalg.solve(
                            np.linalg.cholesky(covs[k]),
                            gtsam.Pose3.Logmap(result.atPose3(int(vl_state[k])).between(gtsam.Pose3(vl_T_mb[k]))),
                        )
                    )
                )
            )
            for k in range(len(vl_T_mb))
        ]
    )


@dataclass(frozen=True)
class _Problem:
    """The factor graph's states and priors: (S,) state times and (S, 4, 4) T_odom_base there,
    the (P,) VLoc results inside the odometry span (`vidx`), their T_map_base and states."""

    st_t: I64
    st_T: F64
    vidx: I64
    vl_T_mb: F64
    vl_state: I64
    T_map_odom0: F64  # the consensus initial T_map_odom


def _checked(odom_times_ns: NDArray[np.integer], T_odom_base: NDArray[np.floating], vloc_times_ns: NDArray[np.integer],
             T_map_camera: NDArray[np.floating]) -> tuple[I64, F64, I64, F64]:
    """The inputs as int64 / float64 arrays; ValueError on bad shapes or odometry times that do
    not increase."""
    t = np.asarray(odom_times_ns, dtype=np.int64)
    To = np.asarray(T_odom_base, dtype=np.float64)
    tv = np.asarray(vloc_times_ns, dtype=np.int64)
    Tv = np.asarray(T_map_camera, dtype=np.float64)
    if t.ndim != 1 or len(t) < 2 or To.shape != (len(t), 4, 4):
        raise ValueError(
            f"need (N>=2,) odometry times and (N,4,4) poses, got {t.shape} and {To.shape}"
        )
    if np.any(np.diff(t) <= 0):
        raise ValueError("odometry times must be strictly increasing")
    if tv.ndim != 1 or Tv.shape != (len(tv), 4, 4):
        raise ValueError(f"need (M,) VLoc times and (M,4,4) poses, got {tv.shape} and {Tv.shape}")
    return t, To, tv, Tv


def _problem(t: I64, To: F64, tv: I64, Tv: F64, T_cb: F64, params: FusionParams) -> _Problem:
    """States at the decimated odometry keyframes plus the VLoc capture times inside the
    odometry span (odometry interpolated there), each VLoc pose moved to base_link by `T_cb`
    (T_camera_base)."""
    vidx = np.nonzero((tv >= t[0]) & (tv <= t[-1]))[0]
    if len(vidx) == 0:
        raise ValueError("no VLoc result falls inside the odometry time span")
    kf = _keyframes(t, To, params)
    st_t = np.unique(np.concatenate([t[kf], tv[vidx]]))
    st_T = np.stack([interpolate_pose_at(int(x), t, To) for x in st_t])
    vl_T_mb = np.stack([Tv[i] @ T_cb for i in vidx])
    vl_state = np.searchsorted(st_t, tv[vidx])
    T_map_odom0 = _consensus_map_odom(
        np.stack([vl_T_mb[k] @ invert(st_T[s]) for k, s in enumerate(vl_state)]), params
    )
    return _Problem(st_t, st_T, vidx, vl_T_mb, vl_state, T_map_odom0)


def _solve_gated(pb: _Problem, covs: list[F64], params: FusionParams) -> tuple[gtsam.Values, NDArray[np.bool_], int]:
    """LM on the odometry chain and the VLoc priors (`covs`: GTSAM-order covariances of
    T_map_base); while `gate_chi2` > 0, the priors beyond it are dropped and LM runs again
    from the last solution (at most 4 solves, until the kept set stops changing or would be
    empty). The solution, the priors kept, and the LM iterations of all solves."""
    base, values = _odometry_chain(pb.st_T, pb.T_map_odom0, params)
    active = np.ones(len(pb.vidx), dtype=bool)
    iterations = 0
    result = values
    for _round in range(4):
        graph = gtsam.NonlinearFactorGraph(base)
        for kk in np.nonzero(active)[0]:
            graph.add(gtsam.PriorFactorPose3(int(pb.vl_state[kk]), gtsam.Pose3(pb.vl_T_mb[kk]),
                                             vloc_noise_model(covs[kk], params)))
        lm = gtsam.LevenbergMarquardtOptimizer(graph, result, gtsam.LevenbergMarquardtParams())
        result = lm.optimize()
        iterations += lm.iterations()
        if params.gate_chi2 <= 0:
            break
        new_active = _prior_mahalanobis2(result, pb.vl_state, pb.vl_T_mb, covs) <= params.gate_chi2
        if not new_active.any() or np.array_equal(new_active, active):
            break
        active = new_active
    return result, active, iterations


def refine_session(
    odom_times_ns: NDArray[np.integer],
    T_odom_base: NDArray[np.floating],
    vloc_times_ns: NDArray[np.integer],
    T_map_camera: NDArray[np.floating],
    vloc_covariances: NDArray[np.floating] | None,
    params: FusionParams,
    T_base_camera: NDArray[np.floating],
) -> BatchResult:
    """Optimise a session offline.

    Args:
        odom_times_ns: (N,) increasing int ns; T_odom_base: (N, 4, 4).
        vloc_times_ns: (M,) capture times int ns; T_map_camera: (M, 4, 4).
        vloc_covariances: (M, 6, 6) ROS order (x, y, z, rx, ry, rz) of T_map_camera, or
            None for the `vloc_sigma_*` defaults.
        params: the same FusionParams as the online filter.
        T_base_camera: 4x4 camera (optical) extrinsics in base_link.

    Returns:
        BatchResult: (N,) times, (N, 4, 4) T_map_base at every odometry time, BatchInfo.
    Raises:
        ValueError: no usable VLoc result, bad shapes or non-rigid poses.
    """
    t, To, tv, Tv = _checked(odom_times_ns, T_odom_base, vloc_times_ns, T_map_camera)
    T_bc = valid_pose(T_base_camera)
    if T_bc is None:
        raise ValueError("T_base_camera must be a finite 4x4 rigid transform")
    Ad = gtsam.Pose3(T_bc).AdjointMap()
    pb = _problem(t, To, tv, Tv, invert(T_bc), params)

    def cov_of(i: int) -> F64:
        if vloc_covariances is None:
            c = params.vloc_cov_gtsam()
        else:
            c = ros_to_gtsam_covariance(np.asarray(vloc_covariances, dtype=np.float64)[i])
        return Ad @ c @ Ad.T

    result, active, iterations = _solve_gated(pb, [cov_of(int(i)) for i in pb.vidx], params)
    est = np.stack([result.atPose3(k).matrix() for k in range(len(pb.st_t))])
    prev = np.clip(np.searchsorted(pb.st_t, t, side="right") - 1, 0, len(pb.st_t) - 1)
    out = est[prev] @ invert(pb.st_T[prev]) @ To
    outside = int(len(tv) - len(pb.vidx))
    info = BatchInfo(len(pb.st_t), int(active.sum()), int((~active).sum()), outside, iterations)
    return BatchResult(t, out, info)
