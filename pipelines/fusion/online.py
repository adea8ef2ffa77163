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

from collections import Counter, deque
from dataclasses import dataclass
from typing import Any

import gtsam
import numpy as np
from numpy.typing import NDArray

from litevloc.base.geometry import gtsam_to_ros_covariance, invert, ros_to_gtsam_covariance
from litevloc.base.params.fusion import FusionParams
from litevloc.base.stats import percentile
from litevloc.pipelines.fusion.graph_ops import (
    carried_cov,
    estimate_pose3,
    odom_cov,
    pose3,
    valid_cov,
    valid_pose,
    vloc_noise_model,
)
from litevloc.pipelines.fusion.odometry_buffer import OdometryBuffer
from litevloc.pipelines.fusion.votes import Candidate, agree, carried_late, combines
from litevloc.pipelines.fusion.window import SmootherWindow

F64 = NDArray[np.float64]

__all__ = [
    "FusedPose",
    "FusionParams",
    "OnlineFusion",
    "VlocUpdate",
]


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


def _frozen(a: F64) -> F64:
    """`a` made read-only: a fused pose is a value that its readers (the VLoc thread's prior among
    them) share and never change."""
    a.flags.writeable = False
    return a


class OnlineFusion:
    """Fixed-lag pose-graph fusion; see the module docstring for the model.

    Not thread-safe: call it from one thread (the runtime's fusion stage).
    `T_base_camera`: 4x4 extrinsics of the camera (optical) in base_link, from config.
    """

    def __init__(self, params: FusionParams, T_base_camera: NDArray[np.floating]) -> None:
        T = valid_pose(T_base_camera)
        if T is None:
            raise ValueError("T_base_camera must be a finite 4x4 rigid transform")
        self.params = params
        self.T_base_camera = T
        self.T_camera_base = invert(T)
        self._Ad_bc = gtsam.Pose3(T).AdjointMap()  # maps camera-frame twists to base frame
        self._odom = OdometryBuffer(params.odom_buffer_s, params.max_future_s)
        self._last_odom_t: int | None = None
        self._counts: Counter[str] = Counter()
        self._vloc_reasons: Counter[str] = Counter()
        self._odom_rejects: Counter[str] = Counter()
        self._update_ms: deque[float] = deque(maxlen=20000)
        self._candidates: deque[Candidate] = deque(maxlen=max(params.init_votes, 1))
        self._rejected: deque[Candidate] = deque(maxlen=max(params.reinit_after_rejects, 1))
        self._reanchor: deque[Candidate] = deque(maxlen=max(params.init_votes, 1))
        self._consecutive_rejects = 0
        self._w = SmootherWindow(params, self._counts, self._update_ms)

    def _initialise(self, cands: list[Candidate], reason: str) -> VlocUpdate:
        """Start the graph from mutually consistent VLoc results (`cands`, newest last).

        The first state sits at the oldest usable capture time (within lag_s / 2 of the
        newest and inside the odometry buffer); buffered odometry since then becomes
        keyframes, and the other results are added as ordinary (ungated) priors, so all
        the votes inform the start instead of only one.
        """
        newest = cands[-1]
        w = self._w
        oldest_ok = max(newest.t_ns - int(self.params.lag_s * 0.5e9), self._odom.first_t)
        usable = sorted((c for c in cands if c.t_ns >= oldest_ok), key=lambda c: c.t_ns)
        if not usable:
            usable = [newest]
        c = usable[0]
        if not w.start(c.t_ns, c.T_map_base, c.T_odom_base, c.cov):
            return VlocUpdate(False, "solver_error")
        # Odometry that arrived after the capture time becomes keyframes now.
        for t, T in list(self._odom):
            if t > c.t_ns and w.initialised:
                w.maybe_keyframe(t, T)
        for other in usable[1:]:
            if w.initialised:
                self._attach_prior(other, gate=False)
        if not w.initialised:
            return VlocUpdate(False, "solver_error")
        self._candidates.clear()
        self._rejected.clear()
        self._reanchor.clear()
        self._consecutive_rejects = 0
        self._counts[reason] += 1
        return VlocUpdate(True, reason, None)

    def flush(self) -> None:
        """Add the keyframe that `add_odometry(..., defer_update=True)` left due (one smoother
        update, ~1-3 ms); nothing when none is pending. `add_odometry` and `add_vloc` call it
        first, so a caller that never calls it gets every keyframe one message later."""
        self._w.flush()

    # ------------------------------------------------------------------ odometry
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
        T = valid_pose(T_odom_base)
        if T is None:
            self._odom_rejects["invalid_pose"] += 1
            return None
        try:
            cov = valid_cov(covariance)
        except ValueError:
            self._odom_rejects["invalid_covariance"] += 1
            return None
        if self._last_odom_t is not None and t_ns <= self._last_odom_t:
            self._odom_rejects["time_not_increasing"] += 1
            return None
        self._last_odom_t = t_ns
        self._odom.add(t_ns, T)
        if cov is not None:
            self._counts["odometry_with_covariance"] += 1  # validated; the model sets the noise
        w = self._w
        if not w.initialised:
            return None
        if defer_update:
            D = w.due_increment(t_ns, T)
            if D is not None:
                w.pending_keyframe = (t_ns, T, D)
        else:
            w.maybe_keyframe(t_ns, T)
            if not w.initialised:  # the solver failed on this keyframe (counted)
                return None
        out = self._output(t_ns, T)
        self._counts["fused_outputs"] += 1
        return out

    def _output(self, t_ns: int, T_odom_base: F64) -> FusedPose:
        T_map_base, T_map_odom, cov = self._w.output(T_odom_base)
        return FusedPose(t_ns, _frozen(T_map_base), _frozen(T_map_odom), _frozen(gtsam_to_ros_covariance(cov)), True)

    def current(self) -> FusedPose | None:
        """The fused pose at the newest odometry time (None before initialisation)."""
        if not self._w.initialised or not self._odom:
            return None
        t, T = self._odom.newest
        return self._output(t, T)

    def covariance_now(self) -> F64 | None:
        """Marginal covariance (ROS order) of the newest state, computed now (on demand)."""
        w = self._w
        if not w.initialised:
            return None
        return gtsam_to_ros_covariance(np.asarray(w.smoother.marginalCovariance(w.keys[-1][0])))

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
            if self._w.initialised:
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
        T_mc = valid_pose(T_map_camera)
        if T_mc is None:
            return VlocUpdate(False, "invalid_pose")
        try:
            cov_c = valid_cov(covariance)
        except ValueError:
            return VlocUpdate(False, "invalid_covariance")
        cov = p.vloc_cov_gtsam() if cov_c is None else ros_to_gtsam_covariance(cov_c)
        cov = self._Ad_bc @ cov @ self._Ad_bc.T
        T_mb = T_mc @ self.T_camera_base
        if not self._odom:
            return VlocUpdate(False, "no_odometry")
        T_ob = self._odom.at(t_ns)
        if T_ob is None:
            return VlocUpdate(False, "too_old" if t_ns < self._odom.first_t else "ahead_of_odometry")
        cand = Candidate(t_ns, T_mb, T_ob, cov)
        if not self._w.initialised:
            return self._try_init(cand)
        return self._attach_prior(cand, gate=True)

    def _attach_prior(self, cand: Candidate, gate: bool) -> VlocUpdate:
        """Gate `cand` against the prediction and add it as a prior on the nearest state."""
        p, w = self.params, self._w
        t_ns, T_mb, T_ob, cov = cand.t_ns, cand.T_map_base, cand.T_odom_base, cand.cov
        # Target: the window keyframe nearest in time to the capture time.
        horizon = w.keys[-1][1] - int((p.lag_s - p.keyframe_period_s) * 1e9)
        oldest = max(w.keys[0][1], horizon)
        path = None  # (m, rad) driven since a late capture; a pose inside the window: its short gap's net motion
        if t_ns < oldest - int(p.keyframe_period_s * 0.5e9):
            path = self._odom.path(t_ns, oldest)
            if not carried_late(*path, p):
                return VlocUpdate(False, "too_old")
        key, _, T_key_odom = min(
            (k for k in w.keys if k[1] >= horizon), key=lambda k: abs(k[1] - t_ns)
        )
        D = invert(T_ob) @ T_key_odom  # odometry from capture time to keyframe time
        meas = T_mb @ D
        cov_meas = cov + carried_cov(p, D, path)
        pred = estimate_pose3(w.smoother, key)
        xi = gtsam.Pose3.Logmap(pred.between(pose3(meas)))
        S = w.cov_state + odom_cov(p, w.cov_key_T_odom, w.keys[-1][2]) + cov_meas
        m2_walk = float(xi @ np.linalg.solve(S, xi))  # the graph's own (random-walk) uncertainty
        m2 = float(xi @ np.linalg.solve(S + w.drift_cov(key, T_key_odom), xi))
        if gate and p.gate_chi2 > 0 and m2 > p.gate_chi2:
            self._consecutive_rejects += 1
            self._rejected.append(cand)
            if (
                p.reinit_after_rejects > 0
                and self._consecutive_rejects >= p.reinit_after_rejects
                and agree(list(self._rejected), self._odom, p)
            ):
                return self._initialise(list(self._rejected), "reinitialised")
            return VlocUpdate(False, "gated", m2)
        if gate and p.gate_chi2 > 0 and m2_walk > p.gate_chi2:
            # Only the drift since the last fix explains it: the graph is overconfident, and a
            # robust prior would barely move it. Agreeing such poses restart it where they say.
            self._reanchor.append(cand)
            if len(self._reanchor) >= p.init_votes and agree(list(self._reanchor), self._odom, p):
                return self._initialise(list(self._reanchor), "reanchored")
            return VlocUpdate(False, "reanchor_vote", m2)
        self._consecutive_rejects = 0
        self._rejected.clear()
        self._reanchor.clear()
        if key in w.moments and w.moments[key].length_m > w.fix[0].length_m:
            w.fix = (w.moments[key], T_key_odom[:3, 3].copy())  # the drift restarts here
        graph = gtsam.NonlinearFactorGraph()
        graph.add(gtsam.PriorFactorPose3(key, pose3(meas), vloc_noise_model(cov_meas, self.params)))
        if not w.update(graph, gtsam.Values(), {}):
            return VlocUpdate(False, "solver_error", m2)
        self._counts["priors"] += 1
        return VlocUpdate(True, "accepted", m2)

    def _try_init(self, cand: Candidate) -> VlocUpdate:
        p = self.params
        kept = [c for c in self._candidates if combines(c, cand, self._odom, p)]  # votes too far apart do not combine
        self._candidates.clear()
        self._candidates.extend(kept)
        self._candidates.append(cand)
        if len(self._candidates) >= p.init_votes and agree(list(self._candidates), self._odom, p):
            return self._initialise(list(self._candidates), "initialised")
        return VlocUpdate(False, "awaiting_init")

    # ------------------------------------------------------------------ diagnostics
    @property
    def initialised(self) -> bool:
        return self._w.initialised

    def states_in_graph(self) -> int:
        """Number of pose variables currently in the smoother."""
        return self._w.states()

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
            "window_keys": len(self._w.keys) if self._w.initialised else 0,
            "covariance_computations": self._counts["covariance_computations"],
            "reinitialisations": self._counts["reinitialised"],
            "solver_errors": self._counts["solver_errors"],
            "update_ms_p50": percentile(self._update_ms, 50),
            "update_ms_p99": percentile(self._update_ms, 99),
            "update_ms_max": max(self._update_ms) if self._update_ms else None,
            "updates_timed": len(self._update_ms),
        }
