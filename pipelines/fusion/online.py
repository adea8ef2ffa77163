"""Online pose-graph fusion of late, low-rate VLoc poses with high-rate odometry (GTSAM).

Model
-----
* **States** `x_k` are `T_map_base` at *keyframe* times: an odometry message becomes a
  keyframe when `keyframe_period_s` has passed or the robot moved `keyframe_dist_m` /
  `keyframe_angle_deg` since the last one (100-200 Hz odometry -> ~10 states/s).
* **Odometry**: a `BetweenFactorPose3(x_k-1, x_k, inv(T_odom_base(k-1)) T_odom_base(k))`
  per keyframe; sigmas grow with the increment (`odom_sigma_*`, see FusionParams).
* **VLoc**: a camera pose `T_map_camera` captured at `t_ns` becomes a base pose
  `T_map_base = T_map_camera @ inv(T_base_camera)` (covariance mapped with the adjoint of
  `T_base_camera`). It is applied **at its own capture time**: the odometry between `t_ns`
  and the nearest keyframe time `t_k` (interpolated from the buffered odometry,
  |t_k - t_ns| <= keyframe period / 2) transports it to a `PriorFactorPose3` on `x_k`:
  `T_map_base(t_k) = T_map_base(t_ns) @ inv(T_odom_base(t_ns)) @ T_odom_base(t_k)`, with
  that short gap's odometry noise added to its covariance. A result older than the
  smoother window is carried the same way to the window's oldest state where the odometry
  since its capture moved less than `late_max_travel_m` / `late_max_turn_deg` (a VLoc that
  took 20 s on a robot at rest, or 4-8 s on a moving one), else rejected (`too_old`), never
  applied to the newest state. The carrying noise is the odometry model's over the path
  driven (its length and the turns summed), not the net motion alone, so a pose carried
  through a turn on the spot or a long drive weighs what that odometry is worth.
* **Outliers**: chi-square gating of the Mahalanobis distance between the measurement and
  the predicted state (`S = P_pred + R + Q_drift`, 6 dof), then a robust kernel (Huber or
  Cauchy) on the accepted prior. `P_pred` is the marginal covariance of the newest state,
  computed at most every `covariance_period_s` (never per update) and propagated with the
  odometry noise since. `Q_drift` is the odometry's systematic drift over the keyframe path
  since the last accepted pose (`odom_drift_*`, `drift.drift_covariance`: a heading bias turns
  every later step, a scale error stretches the net displacement; each along the direction the
  path itself gives in the odometry frame, so what a turn moves from sideways to along the track
  stays allowed for), which the graph's random-walk odometry noise (growing with the square root
  of the path) misses: negligible between fixes a few tenths of a second apart, metres after a
  30 m outage.
* **Re-anchoring**: a pose that passes the gate only thanks to `Q_drift` says the graph is
  overconfident (a robust prior would barely move it); it is a vote, and `init_votes`
  consecutive agreeing votes restart the filter from them (`reanchored`).
* **Bounded graph**: GTSAM's `IncrementalFixedLagSmoother` (iSAM2 that marginalises
  states older than `lag_s`): states in the graph ~ lag_s / keyframe_period_s.
* **Initialisation**: once `init_votes` consecutive VLoc poses captured within
  `init_window_s` of each other agree (each, carried by the odometry to the newest's capture,
  within `init_max_trans_m` / `init_max_rot_deg` of it, plus three sigmas of the odometry's
  drift over the path between them; `init_votes = 1` takes the very first
  one; votes captured farther apart still combine where the odometry between them travelled
  less than `init_window_m` and turned less than `init_window_deg` in all: a global
  localization slower than the window, under load, on a robot waiting for its first fix;
  an alias seen again after the robot turned or drove on does not), the first state is put at
  the oldest vote's capture time with its prior, the buffered odometry since becomes
  keyframes, and the other votes are added as priors.
  Before that, `add_odometry` returns None (the message is still buffered and counted).
  After `reinit_after_rejects` consecutive gated rejections that agree among themselves,
  the filter re-initialises from them (recovers from a wrong start or a kidnapping).
  A *vote* (`add_vloc(..., vote_only=True)`: a provisional GL pose that one keyframe alone
  verified) counts only towards initialisation, like an accepted result; once the filter is
  initialised, votes are ignored (`vote_ignored`).
  A GTSAM exception (counted as `solver_errors`) also returns the filter to
  uninitialised, so a numerical failure never kills the fusion stage.
* **Output** at every odometry message: the newest optimised state composed with the
  odometry increments since (`T_map_base`), and the REP-105 correction
  `T_map_odom = T_map_base @ inv(T_odom_base)`; its covariance holds `Q_drift` too, so it
  grows as the odometry's error does while no VLoc pose is accepted.

Frames and orders
-----------------
Poses are 4x4 float64, `T_a_b` maps points from b to a. **Covariances are 6x6 in ROS
order (x, y, z, rot_x, rot_y, rot_z)** — translation first, metres and radians — as a
right (body-frame) perturbation of the pose, like `geometry_msgs/PoseWithCovariance`.
Internally GTSAM uses (rot, trans); the conversion happens at the API boundary.
Odometry noise comes from the `odom_sigma_*` model (a covariance passed to
`add_odometry` is validated, not used).

All GTSAM calls hold the GIL; each update touches a bounded window (tens of states).
"""

from __future__ import annotations

import itertools
import math
import time
from collections import Counter, deque
from dataclasses import dataclass
from typing import Any, cast

import gtsam
import numpy as np
from numpy.typing import NDArray

from litevloc.base.geometry import (
    gtsam_to_ros_covariance,
    interpolate_pose,
    invert,
    ros_to_gtsam_covariance,
    rotation_angle,
)
from litevloc.base.params.fusion import FusionParams
from litevloc.base.stats import percentile
from litevloc.pipelines.fusion.drift import PathMoments, drift_covariance

F64 = NDArray[np.float64]

__all__ = [
    "FusedPose",
    "FusionParams",
    "OnlineFusion",
    "VlocUpdate",
]

_I3 = np.eye(3)
_AGREE_SIGMAS = 3.0  # how far two VLoc poses may differ by the odometry's drift between them
_ROW3 = np.array([0.0, 0.0, 0.0, 1.0])


@dataclass(frozen=True)
class FusedPose:
    """Fused output for one odometry message.

    `T_map_base`, `T_map_odom`: 4x4 float64. `covariance`: 6x6 of `T_map_base`, ROS order
    (x, y, z, rot_x, rot_y, rot_z), body-frame perturbation, m^2 / rad^2 — the newest
    state's marginal (refreshed every `covariance_period_s`) plus odometry noise since.
    """

    t_ns: int
    T_map_base: F64
    T_map_odom: F64
    covariance: F64
    initialised: bool


@dataclass(frozen=True)
class VlocUpdate:
    """What happened to one VLoc result. `reason`: accepted | initialised | reinitialised |
    awaiting_init | gated | too_old | ahead_of_odometry | no_odometry | invalid_pose |
    invalid_covariance | solver_error. `mahalanobis2`: squared Mahalanobis distance to
    the prediction (6 dof) where it was computed."""

    accepted: bool
    reason: str
    mahalanobis2: float | None = None


def _valid_pose(T: NDArray[np.floating]) -> F64 | None:
    """T as a float64 4x4 rigid transform (rotation re-orthonormalised if off by > 1e-9),
    or None if it is not finite / not rigid within 1e-4."""
    A = np.asarray(T, dtype=np.float64)
    if A.shape != (4, 4) or not np.isfinite(A).all():
        return None
    R = A[:3, :3]
    err = float(np.abs(R @ R.T - _I3).max())
    if err > 1e-4 or np.linalg.det(R) < 0 or float(np.abs(A[3] - _ROW3).max()) > 1e-6:
        return None
    out = A.copy()
    if err > 1e-9:  # remove round-off so GTSAM gets an exact rotation
        U, _, Vt = np.linalg.svd(R)
        out[:3, :3] = U @ Vt
    return out


def _inv(T: F64) -> F64:
    """Inverse of one 4x4 rigid transform (cheaper than geometry.invert for a single one)."""
    out = np.eye(4)
    Rt = T[:3, :3].T
    out[:3, :3] = Rt
    out[:3, 3] = -Rt @ T[:3, 3]
    return out


def _angle(R: F64) -> float:
    """Rotation angle (rad) from the trace; accurate enough for noise models and thresholds."""
    return math.acos(max(-1.0, min(1.0, (R[0, 0] + R[1, 1] + R[2, 2] - 1.0) * 0.5)))


def _valid_cov(C: NDArray[np.floating] | None) -> F64 | None:
    if C is None:
        return None
    A = np.asarray(C, dtype=np.float64)
    if A.shape != (6, 6) or not np.all(np.isfinite(A)):
        raise ValueError("covariance must be a finite 6x6 matrix")
    A = 0.5 * (A + A.T)
    if np.linalg.eigvalsh(A).min() <= 0:
        raise ValueError("covariance must be positive definite")
    return A


def _estimate_pose3(smoother: gtsam.IncrementalFixedLagSmoother, key: int) -> gtsam.Pose3:
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


def _pose3(T: F64) -> gtsam.Pose3:
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


@dataclass
class _Candidate:
    t_ns: int
    T_map_base: F64
    T_odom_base: F64
    cov: F64  # gtsam order

    def carried_to(self, other: _Candidate) -> F64:
        """This pose carried by the odometry to `other`'s capture time (T_map_base)."""
        return self.T_map_base @ invert(self.T_odom_base) @ other.T_odom_base


class OnlineFusion:
    """Fixed-lag pose-graph fusion; see the module docstring for the model.

    Not thread-safe: call it from one thread (the runtime's fusion stage).
    `T_base_camera`: 4x4 extrinsics of the camera (optical) in base_link, from config.
    """

    def __init__(self, params: FusionParams, T_base_camera: NDArray[np.floating]) -> None:
        T = _valid_pose(T_base_camera)
        if T is None:
            raise ValueError("T_base_camera must be a finite 4x4 rigid transform")
        self.params = params
        self.T_base_camera = T
        self.T_camera_base = invert(T)
        self._Ad_bc = gtsam.Pose3(T).AdjointMap()  # maps camera-frame twists to base frame
        self._odom: deque[tuple[int, F64]] = deque()
        self._last_odom_t: int | None = None
        self._counts: Counter[str] = Counter()
        self._vloc_reasons: Counter[str] = Counter()
        self._odom_rejects: Counter[str] = Counter()
        self._update_ms: deque[float] = deque(maxlen=20000)
        self._candidates: deque[_Candidate] = deque(maxlen=max(params.init_votes, 1))
        self._rejected: deque[_Candidate] = deque(maxlen=max(params.reinit_after_rejects, 1))
        self._reanchor: deque[_Candidate] = deque(maxlen=max(params.init_votes, 1))
        self._consecutive_rejects = 0
        self._reset_graph()

    # ------------------------------------------------------------------ graph state
    def _reset_graph(self) -> None:
        isam = gtsam.ISAM2Params()
        isam.setRelinearizeThreshold(0.01)
        isam.relinearizeSkip = 1
        isam.findUnusedFactorSlots = True  # keeps the factor table from growing
        self._smoother = gtsam.IncrementalFixedLagSmoother(self.params.lag_s, isam)
        self._keys: deque[tuple[int, int, F64]] = deque()  # (key, t_ns, T_odom_base) in the window
        self._next_index = 0
        self._t0_ns: int | None = None
        self._initialised = False
        self._last_est: F64 | None = None  # T_map_base of the newest key
        self._cov_state: F64 = np.zeros((6, 6))  # gtsam order, marginal of the newest key at _cov_t
        self._cov_t: int | None = None
        self._cov_key_T_odom: F64 = np.eye(4)
        self._pending_keyframe: tuple[int, F64, F64] | None = None  # (t, T_odom_base, D): defer_update=True
        # Keyframe path sums from the filter's start, per window state, and at the newest accepted
        # VLoc pose's state (the drift's origin; kept when that state leaves the window).
        self._moments: dict[int, PathMoments] = {}
        self._fix: tuple[PathMoments, F64] = (PathMoments.zero(), np.zeros(3))

    def _stamp(self, t_ns: int) -> float:
        assert self._t0_ns is not None
        return (t_ns - self._t0_ns) * 1e-9

    def _update(
        self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, stamps: dict[int, float]
    ) -> bool:
        """One smoother update; False (counted, filter reset to uninitialised) if GTSAM throws."""
        ts = gtsam.FixedLagSmootherKeyTimestampMap()
        for k, s in stamps.items():
            cast(Any, ts).insert((k, s))  # gtsam's stub leaves insert untyped
        t0 = time.perf_counter()
        try:
            self._smoother.update(graph, values, ts)
            newest_key = self._keys[-1][0]
            self._last_est = _estimate_pose3(self._smoother, newest_key).matrix()
        except RuntimeError:  # e.g. an indeterminant system: start over from the next VLoc
            self._counts["solver_errors"] += 1
            self._reset_graph()
            return False
        self._update_ms.append((time.perf_counter() - t0) * 1e3)
        horizon = self._keys[-1][1] - int(self.params.lag_s * 1e9)
        while self._keys and self._keys[0][1] < horizon:  # mirror what the smoother marginalised
            self._moments.pop(self._keys.popleft()[0], None)
        return True

    def _odom_cov(self, T_a: F64, T_b: F64) -> F64:
        D = _inv(T_a) @ T_b
        s = self.params.odom_sigmas(math.sqrt(float(D[:3, 3] @ D[:3, 3])), _angle(D[:3, :3]))
        return np.diag(s**2)

    def _initialise(self, cands: list[_Candidate], reason: str) -> VlocUpdate:
        """Start the graph from mutually consistent VLoc results (`cands`, newest last).

        The first state sits at the oldest usable capture time (within lag_s / 2 of the
        newest and inside the odometry buffer); buffered odometry since then becomes
        keyframes, and the other results are added as ordinary (ungated) priors, so all
        the votes inform the start instead of only one.
        """
        newest = cands[-1]
        p = self.params
        oldest_ok = max(newest.t_ns - int(p.lag_s * 0.5e9), self._odom[0][0])
        usable = sorted((c for c in cands if c.t_ns >= oldest_ok), key=lambda c: c.t_ns)
        if not usable:
            usable = [newest]
        c = usable[0]
        self._reset_graph()
        self._t0_ns = c.t_ns
        key = gtsam.symbol("x", self._next_index)
        self._next_index += 1
        self._keys.append((key, c.t_ns, c.T_odom_base))
        self._moments[key] = PathMoments.zero()
        self._fix = (PathMoments.zero(), c.T_odom_base[:3, 3].copy())
        graph = gtsam.NonlinearFactorGraph()
        graph.add(
            gtsam.PriorFactorPose3(
                key, _pose3(c.T_map_base), gtsam.noiseModel.Gaussian.Covariance(c.cov)
            )
        )
        values = gtsam.Values()
        values.insert(key, _pose3(c.T_map_base))
        if not self._update(graph, values, {key: 0.0}):
            return VlocUpdate(False, "solver_error")
        self._initialised = True
        self._cov_state = c.cov.copy()
        self._cov_t = c.t_ns
        self._cov_key_T_odom = c.T_odom_base
        # Odometry that arrived after the capture time becomes keyframes now.
        for t, T in list(self._odom):
            if t > c.t_ns and self._initialised:
                self._maybe_keyframe(t, T)
        for other in usable[1:]:
            if self._initialised:
                self._attach_prior(other, gate=False)
        if not self._initialised:
            return VlocUpdate(False, "solver_error")
        self._candidates.clear()
        self._rejected.clear()
        self._reanchor.clear()
        self._consecutive_rejects = 0
        self._counts[reason] += 1
        return VlocUpdate(True, reason, None)

    def _due_increment(self, t_ns: int, T_odom_base: F64) -> F64 | None:
        """The odometry increment from the newest keyframe when a new keyframe is due, else None."""
        _, t_prev, T_prev = self._keys[-1]
        D = _inv(T_prev) @ T_odom_base
        p = self.params
        due = (
            (t_ns - t_prev) >= p.keyframe_period_s * 1e9
            or float(D[:3, 3] @ D[:3, 3]) >= p.keyframe_dist_m**2
            or _angle(D[:3, :3]) >= math.radians(p.keyframe_angle_deg)
        )
        return D if due else None

    def flush(self) -> None:
        """Add the keyframe that `add_odometry(..., defer_update=True)` left due (one smoother
        update, ~1-3 ms); nothing when none is pending. `add_odometry` and `add_vloc` call it
        first, so a caller that never calls it gets every keyframe one message later."""
        pending, self._pending_keyframe = self._pending_keyframe, None
        if pending is not None and self._initialised:
            self._add_keyframe(*pending)

    def _maybe_keyframe(self, t_ns: int, T_odom_base: F64) -> None:
        D = self._due_increment(t_ns, T_odom_base)
        if D is not None:
            self._add_keyframe(t_ns, T_odom_base, D)

    def _add_keyframe(self, t_ns: int, T_odom_base: F64, D: F64) -> None:
        """A new state at `t_ns`, `D` (odometry) after the newest keyframe: one smoother update."""
        key_prev, _, T_prev = self._keys[-1]
        p = self.params
        key = gtsam.symbol("x", self._next_index)
        self._next_index += 1
        graph = gtsam.NonlinearFactorGraph()
        noise = gtsam.noiseModel.Gaussian.Covariance(self._odom_cov(T_prev, T_odom_base))
        graph.add(gtsam.BetweenFactorPose3(key_prev, key, _pose3(D), noise))
        values = gtsam.Values()
        assert self._last_est is not None
        values.insert(key, _pose3(self._last_est @ D))
        self._keys.append((key, t_ns, T_odom_base))
        self._moments[key] = self._moments[key_prev].step(T_prev[:3, 3], T_odom_base[:3, 3])
        self._counts["keyframes"] += 1
        if not self._update(graph, values, {key: self._stamp(t_ns)}):
            return
        if self._cov_t is None or t_ns - self._cov_t >= p.covariance_period_s * 1e9:
            try:
                self._cov_state = np.asarray(
                    self._smoother.marginalCovariance(key), dtype=np.float64
                )
            except RuntimeError:  # keep the previous covariance; counted
                self._counts["solver_errors"] += 1
            self._cov_t = t_ns
            self._cov_key_T_odom = T_odom_base
            self._counts["covariance_computations"] += 1

    # ------------------------------------------------------------------ odometry
    def _odom_at(self, t_ns: int) -> F64 | None:
        """T_odom_base at t_ns interpolated from the buffer (None outside it)."""
        if not self._odom:
            return None
        t_first, t_last = self._odom[0][0], self._odom[-1][0]
        if t_ns < t_first:
            return None
        if t_ns >= t_last:
            if t_ns - t_last > self.params.max_future_s * 1e9:
                return None
            if t_ns == t_last or len(self._odom) < 2:
                return self._odom[-1][1]
            (tp, Tp), (tl, Tl) = self._odom[-2], self._odom[-1]
            return interpolate_pose(
                Tp, Tl, (t_ns - tp) / (tl - tp)
            )  # s > 1: constant-velocity extrapolation
        times = [t for t, _ in self._odom]  # bounded (odom_buffer_s of messages)
        i = int(np.searchsorted(times, t_ns, side="right"))
        t0, T0 = self._odom[i - 1]
        t1, T1 = self._odom[i]
        return interpolate_pose(T0, T1, (t_ns - t0) / (t1 - t0))

    def add_odometry(
        self,
        t_ns: int,
        T_odom_base: NDArray[np.floating],
        covariance: NDArray[np.floating] | None = None,
        *,
        defer_update: bool = False,
    ) -> FusedPose | None:
        """Feed one odometry message; returns the fused pose at t_ns (None before init).

        `defer_update`: when this message makes a new keyframe due, the pose is computed from
        the current estimate and the smoother update (the only costly step: ~1-3 ms, every
        `keyframe_period_s`) is left for `flush()`, so a caller can publish the pose first. The
        keyframe's factor is the same either way; such a message's pose lacks what that update
        moves the estimate (iSAM2 converges over updates; a 90 s synthetic session: 99 % of the
        poses identical, at most 1.2 cm apart, the same ATE; tests/pipelines/fusion).

        A message with a non-finite or non-rigid pose, a bad covariance, or a time not
        after the previous message is rejected, counted in `stats()["odometry_rejected"]`,
        and answered with None. Every valid message after initialisation gets a FusedPose.
        `covariance` (optional, 6x6 ROS order, of the increment since the previous message)
        is validated; the between-factor noise comes from the `odom_sigma_*` model, because
        driver-reported odometry covariances are rarely calibrated.
        """
        self._counts["odometry"] += 1
        self.flush()
        t_ns = int(t_ns)
        T = _valid_pose(T_odom_base)
        if T is None:
            self._odom_rejects["invalid_pose"] += 1
            return None
        try:
            cov = _valid_cov(covariance)
        except ValueError:
            self._odom_rejects["invalid_covariance"] += 1
            return None
        if self._last_odom_t is not None and t_ns <= self._last_odom_t:
            self._odom_rejects["time_not_increasing"] += 1
            return None
        self._last_odom_t = t_ns
        self._odom.append((t_ns, T))
        horizon = t_ns - int(self.params.odom_buffer_s * 1e9)
        while len(self._odom) > 2 and self._odom[1][0] < horizon:
            self._odom.popleft()
        if cov is not None:
            self._counts["odometry_with_covariance"] += 1  # validated; the model sets the noise
        if not self._initialised:
            return None
        if defer_update:
            D = self._due_increment(t_ns, T)
            if D is not None:
                self._pending_keyframe = (t_ns, T, D)
        else:
            self._maybe_keyframe(t_ns, T)
            if not self._initialised:  # the solver failed on this keyframe (counted)
                return None
        out = self._output(t_ns, T)
        self._counts["fused_outputs"] += 1
        return out

    def _output(self, t_ns: int, T_odom_base: F64) -> FusedPose:
        assert self._last_est is not None
        key, _, T_key_odom = self._keys[-1]
        T_map_odom = self._last_est @ _inv(T_key_odom)
        T_map_base = T_map_odom @ T_odom_base
        # The drift up to the newest keyframe, in the frame of the base now.
        T_drift = np.vstack([np.hstack([T_odom_base[:3, :3], T_key_odom[:3, 3:4]]), _ROW3])
        cov = (
            self._cov_state
            + self._odom_cov(self._cov_key_T_odom, T_odom_base)
            + self._drift_cov(key, T_drift)
        )
        return FusedPose(t_ns, T_map_base, T_map_odom, gtsam_to_ros_covariance(cov), True)

    def current(self) -> FusedPose | None:
        """The fused pose at the newest odometry time (None before initialisation)."""
        if not self._initialised or not self._odom:
            return None
        t, T = self._odom[-1]
        return self._output(t, T)

    def covariance_now(self) -> F64 | None:
        """Marginal covariance (ROS order) of the newest state, computed now (on demand)."""
        if not self._initialised:
            return None
        return gtsam_to_ros_covariance(np.asarray(self._smoother.marginalCovariance(self._keys[-1][0])))

    # ------------------------------------------------------------------ VLoc
    def add_vloc(
        self,
        t_ns: int,
        T_map_camera: NDArray[np.floating],
        covariance: NDArray[np.floating] | None = None,
        vote_only: bool = False,
    ) -> VlocUpdate:
        """Fuse one VLoc result captured at `t_ns` (may be older than the newest odometry).

        `covariance`: 6x6 ROS order of `T_map_camera` (body-frame perturbation); None uses
        the `vloc_sigma_*` parameters. `vote_only`: an initialisation vote (see the module
        docstring), ignored once initialised. Returns what happened (also counted in `stats()`).
        """
        self.flush()
        if vote_only:
            self._counts["votes"] += 1
            if self._initialised:
                self._vloc_reasons["vote_ignored"] += 1
                return VlocUpdate(False, "vote_ignored")
            res = self._add_vloc(int(t_ns), T_map_camera, covariance)
            self._vloc_reasons[f"vote_{res.reason}"] += 1
            return res
        self._counts["vloc"] += 1
        res = self._add_vloc(int(t_ns), T_map_camera, covariance)
        self._vloc_reasons[res.reason] += 1
        return res

    def _add_vloc(
        self, t_ns: int, T_map_camera: NDArray[np.floating], covariance: NDArray[np.floating] | None
    ) -> VlocUpdate:
        p = self.params
        T_mc = _valid_pose(T_map_camera)
        if T_mc is None:
            return VlocUpdate(False, "invalid_pose")
        try:
            cov_c = _valid_cov(covariance)
        except ValueError:
            return VlocUpdate(False, "invalid_covariance")
        cov = p.vloc_cov_gtsam() if cov_c is None else ros_to_gtsam_covariance(cov_c)
        cov = self._Ad_bc @ cov @ self._Ad_bc.T
        T_mb = T_mc @ self.T_camera_base
        if not self._odom:
            return VlocUpdate(False, "no_odometry")
        T_ob = self._odom_at(t_ns)
        if T_ob is None:
            return VlocUpdate(False, "too_old" if t_ns < self._odom[0][0] else "ahead_of_odometry")
        cand = _Candidate(t_ns, T_mb, T_ob, cov)
        if not self._initialised:
            return self._try_init(cand)
        return self._attach_prior(cand, gate=True)

    def _attach_prior(self, cand: _Candidate, gate: bool) -> VlocUpdate:
        """Gate `cand` against the prediction and add it as a prior on the nearest state."""
        p = self.params
        t_ns, T_mb, T_ob, cov = cand.t_ns, cand.T_map_base, cand.T_odom_base, cand.cov
        # Target: the window keyframe nearest in time to the capture time.
        horizon = self._keys[-1][1] - int((p.lag_s - p.keyframe_period_s) * 1e9)
        oldest = max(self._keys[0][1], horizon)
        path = None  # (m, rad) driven since a late capture; a pose inside the window: its short gap's net motion
        if t_ns < oldest - int(p.keyframe_period_s * 0.5e9):
            path = self._odometry_path(t_ns, oldest)
            if not self._carried_late(*path):
                return VlocUpdate(False, "too_old")
        key, _, T_key_odom = min(
            (k for k in self._keys if k[1] >= horizon), key=lambda k: abs(k[1] - t_ns)
        )
        D = invert(T_ob) @ T_key_odom  # odometry from capture time to keyframe time
        meas = T_mb @ D
        cov_meas = cov + self._carried_cov(D, path)
        pred = _estimate_pose3(self._smoother, key)
        xi = gtsam.Pose3.Logmap(pred.between(_pose3(meas)))
        S = self._cov_state + self._odom_cov(self._cov_key_T_odom, self._keys[-1][2]) + cov_meas
        m2_walk = float(xi @ np.linalg.solve(S, xi))  # the graph's own (random-walk) uncertainty
        m2 = float(xi @ np.linalg.solve(S + self._drift_cov(key, T_key_odom), xi))
        if gate and p.gate_chi2 > 0 and m2 > p.gate_chi2:
            self._consecutive_rejects += 1
            self._rejected.append(cand)
            if (
                p.reinit_after_rejects > 0
                and self._consecutive_rejects >= p.reinit_after_rejects
                and self._agree(list(self._rejected))
            ):
                return self._initialise(list(self._rejected), "reinitialised")
            return VlocUpdate(False, "gated", m2)
        if gate and p.gate_chi2 > 0 and m2_walk > p.gate_chi2:
            # Only the drift since the last fix explains it: the graph is overconfident, and a
            # robust prior would barely move it. Agreeing such poses restart it where they say.
            self._reanchor.append(cand)
            if len(self._reanchor) >= p.init_votes and self._agree(list(self._reanchor)):
                return self._initialise(list(self._reanchor), "reanchored")
            return VlocUpdate(False, "reanchor_vote", m2)
        self._consecutive_rejects = 0
        self._rejected.clear()
        self._reanchor.clear()
        if key in self._moments and self._moments[key].length_m > self._fix[0].length_m:
            self._fix = (self._moments[key], T_key_odom[:3, 3].copy())  # the drift restarts here
        graph = gtsam.NonlinearFactorGraph()
        graph.add(gtsam.PriorFactorPose3(key, _pose3(meas), vloc_noise_model(cov_meas, self.params)))
        if not self._update(graph, gtsam.Values(), {}):
            return VlocUpdate(False, "solver_error", m2)
        self._counts["priors"] += 1
        return VlocUpdate(True, "accepted", m2)

    def _carried_late(self, path_m: float, path_rad: float) -> bool:
        """Whether a pose captured before the window may be carried to its oldest state by the
        buffered odometry, which drove `path_m` and turned `path_rad` since the capture: less
        than `late_max_travel_m` and `late_max_turn_deg` (the carrying adds that odometry's
        noise to the pose's covariance, `_carried_cov`)."""
        p = self.params
        return p.late_max_travel_m > 0 and path_m < p.late_max_travel_m and path_rad < math.radians(
            p.late_max_turn_deg)

    def _agree(self, cands: list[_Candidate]) -> bool:
        """Whether every pose, carried by the odometry to the newest one's capture time, lies
        within `init_max_trans_m` / `init_max_rot_deg` of it, widened by three sigmas of the
        odometry's drift over the path between them (`FusionParams.drift_sigmas`). Compared
        where the robot is, not as T_map_odom: a small heading difference moves T_map_odom's
        origin by the robot's distance from it."""
        p = self.params
        ref = cands[-1]
        for c in cands[:-1]:
            if c.t_ns < self._odom[0][0]:  # the odometry between them has left the buffer
                return False
            yaw, along, side = p.drift_sigmas(self._odometry_path(c.t_ns, ref.t_ns)[0])
            pos = along + side
            E = invert(ref.T_map_base) @ c.carried_to(ref)
            if (
                float(np.linalg.norm(E[:3, 3])) > p.init_max_trans_m + _AGREE_SIGMAS * pos
                or rotation_angle(E[:3, :3]) > math.radians(p.init_max_rot_deg) + _AGREE_SIGMAS * yaw
            ):
                return False
        return True

    def _drift_cov(self, key: int, T_odom_base: F64) -> F64:
        """Covariance (GTSAM order, body frame of `T_odom_base`) of the odometry's systematic drift
        over the keyframe path from the newest accepted VLoc pose's state to state `key`
        (`drift.drift_covariance`; zero for a state before that one)."""
        moments, p_fix = self._fix
        p = self.params
        return drift_covariance(
            self._moments[key].since(moments),
            p_fix,
            T_odom_base,
            math.radians(p.odom_drift_yaw_deg_per_m),
            p.odom_drift_trans_per_m,
        )

    def _odometry_path(self, t_a: int, t_b: int) -> tuple[float, float]:
        """(metres travelled, radians turned) by the buffered odometry between two times (t_a <= t_b;
        the messages between them, no interpolation at the ends): the path, not the net motion,
        so driving out and back or a turn on the spot counts in full."""
        steps = [T for t, T in self._odom if t_a <= t <= t_b]
        dist = turn = 0.0
        for T0, T1 in itertools.pairwise(steps):
            D = _inv(T0) @ T1
            dist += math.sqrt(float(D[:3, 3] @ D[:3, 3]))
            turn += _angle(D[:3, :3])
        return dist, turn

    def _odometry_within(self, t_a: int, t_b: int, max_m: float, max_deg: float) -> bool:
        """Whether the buffered odometry between two times travelled less than `max_m` metres
        and turned less than `max_deg` degrees in all (`_odometry_path`)."""
        dist, turn = self._odometry_path(t_a, t_b)
        return dist < max_m and turn < math.radians(max_deg)

    def _carried_cov(self, D: F64, path: tuple[float, float] | None) -> F64:
        """Noise (GTSAM order) of the odometry `D` that carries a VLoc pose from its capture time to
        its keyframe's: the odometry model over the larger of the net motion and, for a late pose,
        the `path` (m, rad) driven since its capture (a pose carried through a turn on the spot, or
        out and back, is as uncertain as the turn or the drive made it)."""
        net_m, net_rad = math.sqrt(float(D[:3, 3] @ D[:3, 3])), _angle(D[:3, :3])
        path_m, path_rad = path if path is not None else (0.0, 0.0)
        return np.diag(self.params.odom_sigmas(max(net_m, path_m), max(net_rad, path_rad)) ** 2)

    def _combines(self, old: _Candidate, new: _Candidate) -> bool:
        """Whether an earlier vote may combine with a new one (see the module docstring)."""
        p = self.params
        if new.t_ns - old.t_ns <= p.init_window_s * 1e9:
            return True
        if old.t_ns < self._odom[0][0]:  # its odometry has left the buffer
            return False
        return self._odometry_within(old.t_ns, new.t_ns, p.init_window_m, p.init_window_deg)

    def _try_init(self, cand: _Candidate) -> VlocUpdate:
        kept = [c for c in self._candidates if self._combines(c, cand)]  # votes too far apart do not combine
        self._candidates.clear()
        self._candidates.extend(kept)
        self._candidates.append(cand)
        if len(self._candidates) >= self.params.init_votes and self._agree(list(self._candidates)):
            return self._initialise(list(self._candidates), "initialised")
        return VlocUpdate(False, "awaiting_init")

    # ------------------------------------------------------------------ diagnostics
    @property
    def initialised(self) -> bool:
        return self._initialised

    def states_in_graph(self) -> int:
        """Number of pose variables currently in the smoother."""
        return int(self._smoother.calculateEstimate().size()) if self._initialised else 0

    def stats(self) -> dict[str, Any]:
        """Counters and timings (ms) of smoother updates (keyframes, priors, init)."""
        return {
            "odometry": self._counts["odometry"],
            "odometry_rejected": dict(self._odom_rejects),
            "fused_outputs": self._counts["fused_outputs"],
            "vloc": self._counts["vloc"],
            "votes": self._counts["votes"],  # provisional GL poses offered as initialisation votes
            "vloc_accepted": sum(
                v
                for k, v in self._vloc_reasons.items()
                if k in ("accepted", "initialised", "reinitialised")
            ),
            "vloc_by_reason": dict(self._vloc_reasons),
            "keyframes": self._counts["keyframes"],
            "states_in_graph": self.states_in_graph(),
            "window_keys": len(self._keys) if self._initialised else 0,
            "covariance_computations": self._counts["covariance_computations"],
            "reinitialisations": self._counts["reinitialised"],
            "solver_errors": self._counts["solver_errors"],
            "update_ms_p50": percentile(self._update_ms, 50),
            "update_ms_p99": percentile(self._update_ms, 99),
            "update_ms_max": max(self._update_ms) if self._update_ms else None,
            "updates_timed": len(self._update_ms),
        }
