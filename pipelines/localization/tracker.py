"""The tracking state machine over GL and LL, and the hold of poses the prior cannot confirm.

INIT -> GLOBAL (GL over the whole map) -> TRACKING (LL around the prior) -> LOST
(`local_search.failures_before_lost` LL failures in a row) -> GLOBAL on the next query, each transition
recorded with its reason. A pose (GL, or LL from fusion's prior) that lies outside a fresh fused
prior's gate, or that a stale prior cannot confirm, is held until a later frame repeats it
(`repeat.within_s`, `repeat.within_m`).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from litevloc.base.geometry import relative_pose_error
from litevloc.base.params.localization import LocalizationParams
from litevloc.pipelines.localization import prior as pg
from litevloc.pipelines.localization.global_search import GlobalSearch
from litevloc.pipelines.localization.local_search import LocalSearch
from litevloc.pipelines.localization.prior import Prior
from litevloc.pipelines.localization.refusals import QueryRefusal, refusal_text
from litevloc.pipelines.localization.results import LocalizationResult, refused
from litevloc.pipelines.localization.search_region import SearchRegion
from litevloc.pipelines.localization.tracking import TrackingState, Transition

LL_COST_WINDOW = 50  # LL queries whose median wall time sets the bound on a recovering GL query
_CLOCK_JITTER_S = 1e-3  # timestamps that differ by less than this are the same instant for time windows


@dataclass(frozen=True)
class HeldPose:
    """A GL or LL pose that its fused prior could not confirm (outside its gate, or the prior
    too stale), held until a later frame repeats it (`LocalizationParams.repeat.within_s`, `repeat.within_m`):
    both 4x4 `T_map_camera`, stamp in ns; `inside_gate`: the pose lay inside the prior's gate."""

    t_ns: int
    T_map_camera: NDArray[np.float64]
    prior_T_map_camera: NDArray[np.float64]
    inside_gate: bool = False


class Tracker:
    """The state machine of one localizer: GL (`global_search`) and LL (`local_search`) under `params`."""

    def __init__(self, params: LocalizationParams, global_search: GlobalSearch, local_search: LocalSearch) -> None:
        self.params, self.global_search, self.local_search = params, global_search, local_search
        self.state = TrackingState.INIT
        self.failures = 0
        self.last_pose: NDArray[np.float64] | None = None
        self.last_pose_t_ns = 0
        self.transitions: deque[Transition] = deque(maxlen=100)
        self.held: HeldPose | None = None  # a pose the prior could not confirm, awaiting a repeat
        # wall times (ms) of the last LL queries: their median bounds a recovering GL query (`gl_budget_ms`)
        self.ll_wall_ms: deque[float] = deque(maxlen=LL_COST_WINDOW)

    def process(self, t_ns: int, color: NDArray[np.uint8], depth: NDArray[np.float32] | None,
                K: NDArray[np.float64], prior: Prior | None = None,
                region: SearchRegion | None = None) -> LocalizationResult:
        """One frame through the state machine. The prior (e.g. the fused pose at `t_ns`) is used
        in TRACKING; without one, the last accepted VLoc pose is the prior. In GLOBAL state it can
        accept a single-keyframe GL pose that agrees with it. `region` (an initial pose given by
        the user): GL within it, whatever the state, the prior ignored."""
        p = self.params
        if region is not None:
            self._go(t_ns, TrackingState.GLOBAL, "initial pose given")
            prior = None
        if self.state in (TrackingState.INIT, TrackingState.LOST):
            why = "start-up" if self.state == TrackingState.INIT else "recover from LOST"
            self._go(t_ns, TrackingState.GLOBAL, why)
        if self.state == TrackingState.TRACKING:
            if prior is not None:
                ll_prior = prior
            else:
                assert self.last_pose is not None
                ll_prior = Prior(self.last_pose, (t_ns - self.last_pose_t_ns) * 1e-9, fused=False)
            res = self.local_search.localize(t_ns, color, depth, K, p, ll_prior)
            if "total" in res.timings_ms:
                self.ll_wall_ms.append(res.timings_ms["total"])
            if res.accepted and prior is not None:  # a stale fused prior cannot confirm an LL pose either
                res = self.hold_unless_repeated(res, prior)
            if res.accepted:
                self.failures = 0
                self.last_pose, self.last_pose_t_ns = res.T_map_camera, t_ns
                return res
            if res.refusal is QueryRefusal.NO_NODE_NEAR_PRIOR:
                self._go(t_ns, TrackingState.GLOBAL, "prior far from every map node")
            else:
                self.failures += 1
                if self.failures >= p.local_search.failures_before_lost:
                    self._go(t_ns, TrackingState.LOST, f"{self.failures} consecutive LL failures")
                    self.failures = 0
                return res
        recovering = self.ll_wall_ms if self.last_pose is not None else None  # it has tracked
        self.local_search.full_resolution = ()  # LL after GL starts with the whole first look
        res = self.global_search.localize(t_ns, color, depth, K, p, prior, recovering_ll_ms=recovering, region=region)
        if res.accepted and prior is not None:
            res = self.hold_unless_repeated(res, prior)
        if res.accepted:
            self.failures = 0
            self.last_pose, self.last_pose_t_ns = res.T_map_camera, t_ns
            self._go(t_ns, TrackingState.TRACKING, f"GL verified node {res.ref_node} ({res.n_inliers} inliers)")
        return res

    def hold_unless_repeated(self, res: LocalizationResult, prior: Prior) -> LocalizationResult:
        """An accepted result (GL, or LL with a fused prior) as it is when it lies inside the
        gate of a fresh fused prior (see `prior.fresh`) or repeats the held pose (see
        `LocalizationParams.repeat.within_s`); otherwise it is held and the result says so
        (not accepted)."""
        p = self.params
        if p.repeat.within_s <= 0 or res.T_map_camera is None:
            return res
        T = np.asarray(res.T_map_camera, np.float64)
        T_prior = np.asarray(prior.T_map_camera, np.float64)
        growth = pg.growth_m(p, prior.age_s, True, prior.travel_m)
        gate = pg.gate_toward(p, T, T_prior, pg.gate_m(p, growth, fused=True), prior.cov)
        dt, dr = relative_pose_error(T, T_prior)
        inside, fresh = dt <= gate and dr <= p.prior_gate.deg, pg.fresh(p, growth)
        if inside and fresh:
            self.held = None
            return res
        held = self.held
        if held is not None:
            dt_s = (res.t_ns - held.t_ns) * 1e-9
            # the prior's motion since then (odometry): where the held pose is now
            carried = np.linalg.inv(held.prior_T_map_camera) @ T_prior
            # a robot that stayed put may wait any time for the repeat (GL takes 20 s on a loaded
            # computer); the odometry's drift grows with its motion then, not with the time
            still = float(np.linalg.norm(carried[:3, 3])) <= p.repeat.within_m
            # the window includes its end up to the clock's jitter (frames 1.0 s apart by a camera's clock)
            in_window = 0 < dt_s <= p.repeat.within_s + _CLOCK_JITTER_S
            if in_window or (dt_s > 0 and still):
                expected = held.T_map_camera @ carried
                et, er = relative_pose_error(T, expected)
                tol = p.prior_gate.fused_m + p.prior_gate.rate_fused_mps * min(dt_s, p.repeat.within_s)
                if et <= tol and er <= p.repeat.deg:
                    self.held = None
                    return replace(res, stop_reason=f"{res.stop_reason}; repeats the pose held {dt_s:.2f} s "
                                   f"before ({et:.2f} m, {er:.1f} deg), {gate:.2f} m gate of the prior")
            # in a repeating place the copy outside the gate and the pose inside it come by turns: the
            # copy must not displace the held pose that agrees with the prior, or neither is ever repeated
            if in_window and held.inside_gate and not inside:
                kind = QueryRefusal.HELD_ELSEWHERE
                return refused(res, kind, refusal_text(kind, dt_m=dt, dr_deg=dr, gate_m=gate, dt_s=dt_s))
        self.held = HeldPose(res.t_ns, T, T_prior, inside)
        why = (f"{dt:.2f} m / {dr:.0f} deg from the prior, outside its gate ({gate:.2f} m, {p.prior_gate.deg:g} deg)"
               if not inside else f"the prior is {prior.age_s:.1f} s past its last fix"
               + ("" if prior.travel_m is None else f" and {prior.travel_m:.1f} m of odometry")
               + ", too old to confirm it")
        mode = "GL" if res.mode == "global" else "LL"
        return refused(res, QueryRefusal.HELD, refusal_text(QueryRefusal.HELD, mode=mode, detail=why))

    def carry_over(self, old: Tracker, t_ns: int, reason: str) -> None:
        """Continue `old`'s tracking in this tracker (a new version of the same map, same map frame):
        its state, LL failures, last pose, held pose and LL costs, all in the map frame, so the next
        query is LL around the fused prior, not a cold GL. Nothing here names a node of either map."""
        self.state, self.failures = old.state, old.failures
        self.last_pose, self.last_pose_t_ns = old.last_pose, old.last_pose_t_ns
        self.held = old.held
        self.ll_wall_ms = deque(old.ll_wall_ms, maxlen=LL_COST_WINDOW)
        self.transitions = deque(old.transitions, maxlen=old.transitions.maxlen)
        self.transitions.append(Transition(t_ns, old.state, self.state, reason))

    def _go(self, t_ns: int, to: TrackingState, reason: str) -> None:
        if to != self.state:
            self.transitions.append(Transition(t_ns, self.state, to, reason))
            self.state = to
