"""The fixed-lag smoother window of `OnlineFusion`: keyframe states, their odometry factors, the
newest state's estimate and covariance, and the path sums the drift model needs.

Keys are `gtsam.symbol("x", i)`; `keys` mirrors what the smoother holds: (key, t_ns, T_odom_base)
per state, oldest first. Covariances are 6x6 in GTSAM order (rotation first).
"""

from __future__ import annotations

import math
import time
from collections import Counter, deque
from typing import Any, cast

import gtsam
import numpy as np
from numpy.typing import NDArray

from litevloc.base.params.fusion import FusionParams
from litevloc.pipelines.fusion.drift import PathMoments, drift_covariance
from litevloc.pipelines.fusion.graph_ops import ROW3, angle, estimate_pose3, inv, odom_cov, pose3

F64 = NDArray[np.float64]


class SmootherWindow:
    """GTSAM's `IncrementalFixedLagSmoother` over `lag_s` and the state around it; `reset()`
    empties it (uninitialised). `counts` is the fusion's counter (keyframes, solver errors,
    covariance computations); `update_ms` the smoother update times."""

    def __init__(self, params: FusionParams, counts: Counter[str], update_ms: deque[float]) -> None:
        self.params, self.counts, self.update_ms = params, counts, update_ms
        self.reset()

    def reset(self) -> None:
        isam = gtsam.ISAM2Params()
        isam.setRelinearizeThreshold(0.01)
        isam.relinearizeSkip = 1
        isam.findUnusedFactorSlots = True  # keeps the factor table from growing
        self.smoother = gtsam.IncrementalFixedLagSmoother(self.params.lag_s, isam)
        self.keys: deque[tuple[int, int, F64]] = deque()  # (key, t_ns, T_odom_base) in the window
        self.next_index = 0
        self.t0_ns: int | None = None
        self.initialised = False
        self.last_est: F64 | None = None  # T_map_base of the newest key
        self.cov_state: F64 = np.zeros((6, 6))  # gtsam order, marginal of the newest key at cov_t
        self.cov_t: int | None = None
        self.cov_key_T_odom: F64 = np.eye(4)
        self.pending_keyframe: tuple[int, F64, F64] | None = None  # (t, T_odom_base, D): defer_update=True
        # Keyframe path sums from the filter's start, per window state, and at the newest accepted
        # VLoc pose's state (the drift's origin; kept when that state leaves the window).
        self.moments: dict[int, PathMoments] = {}
        self.fix: tuple[PathMoments, F64] = (PathMoments.zero(), np.zeros(3))

    def _stamp(self, t_ns: int) -> float:
        assert self.t0_ns is not None
        return (t_ns - self.t0_ns) * 1e-9

    def _new_key(self) -> int:
        key = int(gtsam.symbol("x", self.next_index))
        self.next_index += 1
        return key

    def update(self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, stamps: dict[int, float]) -> bool:
        """One smoother update; False (counted, window reset to uninitialised) if GTSAM throws."""
        ts = gtsam.FixedLagSmootherKeyTimestampMap()
        for k, s in stamps.items():
            cast(Any, ts).insert((k, s))  # gtsam's stub leaves insert untyped
        t0 = time.perf_counter()
        try:
            self.smoother.update(graph, values, ts)
            newest_key = self.keys[-1][0]
            self.last_est = estimate_pose3(self.smoother, newest_key).matrix()
        except RuntimeError:  # e.g. an indeterminant system: start over from the next VLoc
            self.counts["solver_errors"] += 1
            self.reset()
            return False
        self.update_ms.append((time.perf_counter() - t0) * 1e3)
        horizon = self.keys[-1][1] - int(self.params.lag_s * 1e9)
        while self.keys and self.keys[0][1] < horizon:  # mirror what the smoother marginalised
            self.moments.pop(self.keys.popleft()[0], None)
        return True

    def start(self, t_ns: int, T_map_base: F64, T_odom_base: F64, cov: F64) -> bool:
        """Restart the window with one state at `t_ns` and its prior (cov: GTSAM order); False if
        the solver failed (the window is then uninitialised)."""
        self.reset()
        self.t0_ns = t_ns
        key = self._new_key()
        self.keys.append((key, t_ns, T_odom_base))
        self.moments[key] = PathMoments.zero()
        self.fix = (PathMoments.zero(), T_odom_base[:3, 3].copy())
        graph = gtsam.NonlinearFactorGraph()
        graph.add(gtsam.PriorFactorPose3(key, pose3(T_map_base), gtsam.noiseModel.Gaussian.Covariance(cov)))
        values = gtsam.Values()
        values.insert(key, pose3(T_map_base))
        if not self.update(graph, values, {key: 0.0}):
            return False
        self.initialised = True
        self.cov_state = cov.copy()
        self.cov_t = t_ns
        self.cov_key_T_odom = T_odom_base
        return True

    def due_increment(self, t_ns: int, T_odom_base: F64) -> F64 | None:
        """The odometry increment from the newest keyframe when a new keyframe is due, else None."""
        _, t_prev, T_prev = self.keys[-1]
        D = inv(T_prev) @ T_odom_base
        p = self.params
        due = (
            (t_ns - t_prev) >= p.keyframe_period_s * 1e9
            or float(D[:3, 3] @ D[:3, 3]) >= p.keyframe_dist_m**2
            or angle(D[:3, :3]) >= math.radians(p.keyframe_angle_deg)
        )
        return D if due else None

    def flush(self) -> None:
        """Add the keyframe a deferred odometry message left due; nothing when none is pending."""
        pending, self.pending_keyframe = self.pending_keyframe, None
        if pending is not None and self.initialised:
            self.add_keyframe(*pending)

    def maybe_keyframe(self, t_ns: int, T_odom_base: F64) -> None:
        D = self.due_increment(t_ns, T_odom_base)
        if D is not None:
            self.add_keyframe(t_ns, T_odom_base, D)

    def add_keyframe(self, t_ns: int, T_odom_base: F64, D: F64) -> None:
        """A new state at `t_ns`, `D` (odometry) after the newest keyframe: one smoother update."""
        key_prev, _, T_prev = self.keys[-1]
        p = self.params
        key = self._new_key()
        graph = gtsam.NonlinearFactorGraph()
        noise = gtsam.noiseModel.Gaussian.Covariance(odom_cov(p, T_prev, T_odom_base))
        graph.add(gtsam.BetweenFactorPose3(key_prev, key, pose3(D), noise))
        values = gtsam.Values()
        assert self.last_est is not None
        values.insert(key, pose3(self.last_est @ D))
        self.keys.append((key, t_ns, T_odom_base))
        self.moments[key] = self.moments[key_prev].step(T_prev[:3, 3], T_odom_base[:3, 3])
        self.counts["keyframes"] += 1
        if not self.update(graph, values, {key: self._stamp(t_ns)}):
            return
        if self.cov_t is None or t_ns - self.cov_t >= p.covariance_period_s * 1e9:
            try:
                self.cov_state = np.asarray(self.smoother.marginalCovariance(key), dtype=np.float64)
            except RuntimeError:  # keep the previous covariance; counted
                self.counts["solver_errors"] += 1
            self.cov_t = t_ns
            self.cov_key_T_odom = T_odom_base
            self.counts["covariance_computations"] += 1

    def output(self, T_odom_base: F64) -> tuple[F64, F64, F64]:
        """(T_map_base, T_map_odom, covariance in GTSAM order) at the odometry pose `T_odom_base`:
        the newest state composed with the odometry since; the covariance holds the drift too."""
        assert self.last_est is not None
        key, _, T_key_odom = self.keys[-1]
        T_map_odom = self.last_est @ inv(T_key_odom)
        T_map_base = T_map_odom @ T_odom_base
        # The drift up to the newest keyframe, in the frame of the base now.
        T_drift = np.vstack([np.hstack([T_odom_base[:3, :3], T_key_odom[:3, 3:4]]), ROW3])
        cov = self.cov_state + odom_cov(self.params, self.cov_key_T_odom, T_odom_base) + self.drift_cov(key, T_drift)
        return T_map_base, T_map_odom, cov

    def drift_cov(self, key: int, T_odom_base: F64) -> F64:
        """Covariance (GTSAM order, body frame of `T_odom_base`) of the odometry's systematic drift
        over the keyframe path from the newest accepted VLoc pose's state to state `key`
        (`drift.drift_covariance`; zero for a state before that one)."""
        moments, p_fix = self.fix
        p = self.params
        return drift_covariance(
            self.moments[key].since(moments),
            p_fix,
            T_odom_base,
            math.radians(p.odom_drift_yaw_deg_per_m),
            p.odom_drift_trans_per_m,
        )

    def states(self) -> int:
        """Number of pose variables currently in the smoother."""
        return int(self.smoother.calculateEstimate().size()) if self.initialised else 0
