"""Coarse-to-fine visual localization against a map-lite `TopoMap`.

* Global localization (GL): VPR top-k retrieval over the map's descriptors, then each
  candidate is verified geometrically (match live vs cached map features, lift the live
  keypoints with the live depth, PnP + RANSAC into the map keyframe). The best verified
  candidate (most PnP inliers) is accepted only if it passes every gate; otherwise the
  result says "not localized" — never a guess.
* Local localization (LL): from a prior `T_map_camera`, the nearest map node and its
  covisibility neighbours within `candidate_radius_m` and `max_view_angle_deg` are ranked
  by descriptor similarity; candidates are tried in that order until one is accepted
  (a rejected candidate hands over to the next).
* Joint refinement (`refine.py`, `LocalizationParams.refine`): an accepted PnP pose is
  refined over its keyframe and up to `refine.max_keyframes - 1` covisible keyframes at once
  (the extra keyframes matched by projection, no second model run); it is accepted only if
  enough keyframes are consistent with the joint pose (this replaces the separate
  confirmation), and its covariance comes from that solve. GL tries VPR candidates in order
  (re-ordered by a cheap mutual-nearest-neighbour count, `gl_rerank`) and stops at the first
  that passes, or when the time budget would be overrun (`gl_time_budget_ms`; while recovering
  after tracking was lost, `lost_cost_ratio` x the median wall time of the last LL queries);
  the result says why in `stop_reason`. `refine.enabled: false` restores the single-keyframe pose with the
  separate confirmation (the behaviour before issue #16).
* Provisional poses: a GL candidate that PnP verifies strongly (`gl_vote_min_inliers`) but that
  no second keyframe confirms is returned, not accepted, as `LocalizationResult.provisional`.
  Fusion may count it as an initialisation vote (several must agree over the odometry between
  them); in GLOBAL state with a prior (the fused pose), one that agrees with the prior within
  the LL prior gate is accepted (the prior is the independent second view).
* A GL pose outside a fused prior's gate gives way to a pose LL verifies at the prior's place
  (`gl_check_prior_place`): in a repeating corridor both verify, the odometry tells them apart.
* Later passes (`passes.py`): a refused GL or LL query is verified again on the same features
  and matches, with the map's depth and then with weak candidates pooled.
* `VisualLocalizer.process` runs the state machine INIT -> GLOBAL -> TRACKING -> LOST ->
  GLOBAL (`tracking.TrackingState`), exposing each transition with its reason.

Pose chain: PnP gives `T_node_live` (live camera -> map keyframe camera), hence
`T_map_live = T_map_node @ T_node_live`. The covariance is that of a right (camera-frame)
perturbation of `T_map_live`, order (tx, ty, tz, rx, ry, rz), see `pipelines.pnp`.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import replace
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from litevloc.base.geometry import backproject_pixels, check_rigid, relative_pose_error
from litevloc.base.loader import ConfigError
from litevloc.base.params.localization import LocalizationParams
from litevloc.pipelines.guided_matching import mutual_nn_pairs
from litevloc.pipelines.localization.distinct import (
    VerifiedPose,
    ambiguity,
    rivals_to_verify,
    same_place,
    strongest_rival,
)
from litevloc.pipelines.localization.passes import (
    VerifyFn,
    pooled,
    pooled_short,
    second_look_nodes,
    with_second_passes,
)
from litevloc.pipelines.localization.prior_gate import narrowed_gate, sigma_along
from litevloc.pipelines.localization.query import Clock, MatchFn, Query, StageTimer, relative_pose, reprojects
from litevloc.pipelines.localization.refine import (
    RefineResult,
    refine_pose,
)
from litevloc.pipelines.localization.results import (
    CandidateAttempt,
    HeldPose,
    LocalizationResult,
    MatchedPixels,
    ProvisionalPose,
)
from litevloc.pipelines.localization.search_region import SearchRegion, nodes_within
from litevloc.pipelines.localization.tracking import TrackingState, Transition
from litevloc.pipelines.pnp import PnpResult, Refusal
from litevloc.pipelines.topomap.types import FeatureSet, TopoMap

LL_COST_WINDOW = 50  # LL queries whose median wall time sets the bound on a recovering GL query

ExtractFn = Callable[[NDArray[np.uint8]], FeatureSet]
DescribeFn = Callable[[NDArray[np.uint8]], NDArray[np.float32]]


class SecondLookFn(Protocol):
    """GL (`local_fused` None) or LL from the prior (`local_fused`: whether it is fusion's)
    verification of `nodes` only, on other features of the same query and map
    (`pipelines.localization.second_look.SecondLook`); None where it does not apply."""

    def __call__(
        self, t_ns: int, color: NDArray[np.uint8], depth: NDArray[np.float32] | None, K: NDArray[np.float64],
        nodes: Sequence[int], prior_T_map_camera: NDArray[np.float64] | None = None, prior_age_s: float = 0.0,
        prior_cov: NDArray[np.float64] | None = None, prior_travel_m: float | None = None,
        local_fused: bool | None = None,
    ) -> LocalizationResult | None: ...


_CLOCK_JITTER_S = 1e-3  # timestamps that differ by less than this are the same instant for time windows


def _refused(res: LocalizationResult, reason: str) -> LocalizationResult:
    """`res` not accepted, for `reason`: its pose, covariance and matches removed."""
    return replace(res, accepted=False, T_map_camera=None, covariance=None, matches=None, reason=reason)


class VisualLocalizer:
    """GL + LL against one map with injected model callables (no I/O, no threads)."""

    def __init__(
        self, topomap: TopoMap, params: LocalizationParams, extract: ExtractFn, describe: DescribeFn, match: MatchFn,
        clock: Clock = time.perf_counter, second_look: SecondLookFn | None = None,
    ) -> None:
        if params.second_look_candidates > 0 and second_look is None:
            raise ConfigError("localization.second_look_candidates > 0 needs the second look's models; this command "
                              "does not load them: set it to 0 here")
        self.second_look = second_look if params.second_look_candidates > 0 else None
        self.map = topomap
        self.clock = clock  # wall time of stages and time budgets (see `StageTimer`)
        self.params = params
        self.extract, self.describe, self.match = extract, describe, match
        self.state = TrackingState.INIT
        self.failures = 0
        self.last_pose: NDArray[np.float64] | None = None
        self.last_pose_t_ns = 0
        self.transitions: deque[Transition] = deque(maxlen=100)
        self.held: HeldPose | None = None  # a pose the prior could not confirm, awaiting a repeat
        # wall times (ms) of the last LL queries: their median bounds a recovering GL query
        # (see `gl_budget_ms`)
        self.ll_wall_ms: deque[float] = deque(maxlen=LL_COST_WINDOW)
        # Covisible neighbours of each node, strongest edge first (computed once, used per query).
        self._neighbours = topomap.covisibility_lists
        self._map_has_depth = topomap.n_nodes > 0 and topomap.keypoint_depth(0) is not None

    # ---------------------------------------------------------------- building blocks
    def _query(
        self, color: NDArray[np.uint8], depth: NDArray[np.float32] | None, K: NDArray[np.float64], timer: StageTimer
    ) -> tuple[Query, NDArray[np.float32]]:
        feats, desc, dimg = self._prepare(color, depth, timer)
        return Query(self.map, self.params, self.match, feats, dimg, K, timer), desc

    def _verify(self, node: int, q: Query, similarity: float,
                params: LocalizationParams | None = None) -> tuple[PnpResult | None, CandidateAttempt]:
        """Match and PnP with `node` under `params` (default: the localizer's)."""
        q.matches(node)  # timed as "match" once; relative_pose then reads the cached matches
        res, n_matches, reason, refusal = relative_pose(
            q.feats, q.depth, q.K, self.map.features[node], self.map.K[node], lambda a, b: q.matches(node),
            params or self.params, q.timer, self.map.keypoint_depth(node), q.pnp_fits,
        )
        return res, CandidateAttempt(node, similarity, n_matches, res.n_inliers if res else 0, reason, refusal)

    def _verify_local(self, node: int, q: Query, similarity: float, guided_prior: NDArray[np.float64] | None,
                      params: LocalizationParams | None = None) -> tuple[PnpResult | None, CandidateAttempt]:
        """`_verify` under `params`, first on matches guided by a fresh prior when given (see
        `LocalizationParams.ll_guided_min_matches`); the matcher's when those are too few or
        their PnP fails."""
        if guided_prior is not None and q.try_guided(node, guided_prior, self.params.ll_guided_min_matches):
            res, att = self._verify(node, q, similarity, params)
            if res is not None and res.accepted:
                return res, att
            q.forget(node)
        return self._verify(node, q, similarity, params)

    def _verify_global(self, node: int, q: Query, similarity: float, verified: list[VerifiedPose] | None = None,
                       params: LocalizationParams | None = None) -> tuple[PnpResult | None, CandidateAttempt]:
        """`_verify`, then the floor check (GL only): a pose resting on one horizontal plane
        comes back as no result, its attempt carrying the reason. Any PnP pose, accepted or
        not, floor or not, is appended to `verified` (evidence for the distinctiveness test)."""
        res, att = self._verify(node, q, similarity, params)
        if verified is not None and res is not None and res.T_target_source is not None:
            verified.append(VerifiedPose(node, self.map.T_map_camera[node] @ res.T_target_source, res.n_inliers))
        flat = "" if res is None or not res.accepted else self._flat_support(node, res, q)
        return (None, replace(att, reason=flat, refusal=Refusal.LATER)) if flat else (res, att)

    def support_height_spread(self, node: int, res: PnpResult, q: Query) -> float:
        """Extent (m) along the map's up vector of the points that support a verified pose
        (10th to 90th percentile of the heights of the matches it explains, `_support_points`);
        inf when the pose or the support is missing. Near 0: every supporting point lies on one
        horizontal plane (the floor or the ceiling), whose tiles repeat in every room and under
        90-degree turns."""
        if res.T_target_source is None or res.n_inliers == 0:
            return float("inf")
        explained, pts = self._explained_matches(node, self.map.T_map_camera[node] @ res.T_target_source, q)
        pts = pts[explained]
        if len(pts) == 0:
            return float("inf")
        h = pts @ np.asarray(self.map.grid.up, dtype=np.float64)
        lo, hi = np.percentile(h, [10.0, 90.0])
        return float(hi - lo)

    def _explained_matches(self, node: int, T_map_live: NDArray[np.float64],
                           q: Query) -> tuple[NDArray[np.bool_], NDArray[np.float64]]:
        """Which matches with `node` (`q.matches` order) the pose `T_map_live` explains within
        the PnP reprojection threshold, either way: a live point (live depth) reprojected into
        the keyframe, or a keyframe point (map depth) projected into the live image; and each
        match's map-frame point (N, 3), the map's where it explains the match, NaN where none."""
        i_live, i_ref = q.matches(node)
        thr = self.params.pnp.reprojection_px
        T_map_kf = self.map.T_map_camera[node]
        live_pts = q.points()[i_live]  # live camera frame, NaN without depth
        kf_px = np.asarray(self.map.features[node].keypoints, dtype=np.float64).reshape(-1, 2)[i_ref]
        live_px = np.asarray(q.feats.keypoints, dtype=np.float64).reshape(-1, 2)[i_live]
        z_kf = self.map.keypoint_depth(node) if self.params.verify_map_depth else None
        kf_pts = (backproject_pixels(self.map.K[node], kf_px, np.asarray(z_kf, np.float64)[i_ref])
                  if z_kf is not None else np.full((len(i_ref), 3), np.nan))
        with np.errstate(invalid="ignore", divide="ignore"):
            ok_live = reprojects(live_pts, np.linalg.inv(T_map_kf) @ T_map_live, self.map.K[node], kf_px, thr)
            ok_kf = reprojects(kf_pts, np.linalg.inv(T_map_live) @ T_map_kf, q.K, live_px, thr)
        out = np.where(ok_kf[:, None], kf_pts @ T_map_kf[:3, :3].T + T_map_kf[:3, 3],
                       live_pts @ T_map_live[:3, :3].T + T_map_live[:3, 3])
        return ok_live | ok_kf, np.asarray(out, dtype=np.float64)

    def _flat_support(self, node: int, res: PnpResult, q: Query) -> str:
        """A rejection reason when a GL pose rests on one horizontal plane only (see
        `LocalizationParams.gl_min_support_height_m`), else ''."""
        need = self.params.gl_min_support_height_m
        if need <= 0:
            return ""
        spread = self.support_height_spread(node, res, q)
        if spread >= need:
            return ""
        return (f"support on one horizontal plane only (inliers span {spread:.2f} m < {need:g} "
                "along up: floor or ceiling tiles repeat)")

    def _result(
        self, t_ns: int, mode: str, best: tuple[int, PnpResult, RefineResult | None] | None,
        attempts: list[CandidateAttempt], timer: StageTimer, fail_reason: str, q: Query | None = None,
    ) -> LocalizationResult:
        if best is None:
            return LocalizationResult(t_ns, mode, False, fail_reason, attempts=tuple(attempts), timings_ms=timer.ms)
        node, res, joint = best
        if joint is not None:
            n_match = sum(joint.matches_per_keyframe.get(k, 0) for k in joint.inliers_per_keyframe)
            return LocalizationResult(
                t_ns, mode, True, "ok", joint.T_map_camera, joint.covariance, node, n_match, joint.n_inliers,
                joint.n_inliers / max(n_match, 1), joint.median_reprojection_px, tuple(attempts), timer.ms,
                tuple(joint.inliers_per_keyframe), matches=self._matched_pixels(q, node, joint.T_map_camera),
            )
        assert res.T_target_source is not None
        T = self.map.T_map_camera[node] @ res.T_target_source
        return LocalizationResult(
            t_ns, mode, True, "ok", T, res.covariance, node, res.n_matches, res.n_inliers, res.inlier_ratio,
            res.median_reprojection_px, tuple(attempts), timer.ms, (node,),
            matches=self._matched_pixels(q, node, T),
        )

    def _single_keyframe(self, node: int, joint: RefineResult) -> ProvisionalPose | None:
        """The joint solve's pose when it failed only for want of a second keyframe and `node`
        itself explains at least `gl_vote_min_inliers` matches under it; else None."""
        rp, need = self.params.refine, self.params.gl_vote_min_inliers
        if need <= 0 or joint.accepted or joint.covariance is None:
            return None
        if joint.consistent_keyframes >= rp.min_keyframes or joint.inliers_per_keyframe.get(node, 0) < need:
            return None
        if joint.shift_m > rp.max_shift_m or joint.shift_deg > rp.max_shift_deg:
            return None
        return ProvisionalPose(joint.T_map_camera, joint.covariance, node, joint.inliers_per_keyframe[node])

    def _prior_growth_m(self, prior_age_s: float, fused: bool, travel_m: float | None = None) -> float:
        """How far the prior may have wandered in `prior_age_s` (m): odometry drift for a fused
        prior (no more than `prior_gate_drift_fused` of the odometry's path `travel_m` since the
        fix where that is known: a robot at rest keeps its prior), the robot's top speed for the
        last VLoc pose."""
        p = self.params
        if not fused:
            return p.prior_gate_rate_mps * max(prior_age_s, 0.0)
        growth = p.prior_gate_rate_fused_mps * max(prior_age_s, 0.0)
        return growth if travel_m is None else min(growth, p.prior_gate_drift_fused * max(travel_m, 0.0))

    def _fresh(self, growth_m: float) -> bool:
        """A prior fresh enough to stand in for a second keyframe (see `confirm_skip_*`)."""
        return growth_m <= self.params.prior_gate_rate_mps * self.params.confirm_skip_max_age_s

    def _gate_m(self, growth_m: float, fused: bool) -> float:
        """The prior gate's radius (m): its base (fused or last-pose prior) + the growth."""
        return (self.params.prior_gate_fused_m if fused else self.params.prior_gate_m) + growth_m

    def _gate_toward(self, T: NDArray[np.float64], prior: NDArray[np.float64], gate_m: float,
                     cov: NDArray[np.float64] | None) -> float:
        """The prior gate's radius (m) toward the pose `T`: `gate_m`, or less where fusion's 3x3
        position covariance `cov` (m^2, map frame) of a fused prior says it is better known
        along that direction: its start + `prior_gate_sigmas` sigmas."""
        d = np.asarray(T, np.float64)[:3, 3] - np.asarray(prior, np.float64)[:3, 3]
        if cov is None or not np.any(d):
            return gate_m
        p = self.params
        return narrowed_gate(gate_m, p.prior_gate_fused_m, p.prior_gate_sigmas, sigma_along(cov, d))

    def _within_gate(self, T: NDArray[np.float64], prior: NDArray[np.float64], gate_m: float,
                     cov: NDArray[np.float64] | None = None) -> bool:
        """The prior gate: within `_gate_toward` and prior_gate_deg."""
        dt, dr = relative_pose_error(T, prior)
        return bool(dt <= self._gate_toward(T, prior, gate_m, cov) and dr <= self.params.prior_gate_deg)

    def _matched_pixels(self, q: Query | None, node: int, T_map_live: NDArray[np.float64]) -> MatchedPixels | None:
        """The cached matches of `q` with `node`, inliers marked under the accepted pose."""
        if q is None:
            return None
        i_live, i_ref = q.matches(node)
        live_px = np.asarray(q.feats.keypoints, dtype=np.float64).reshape(-1, 2)[i_live]
        kf_px = np.asarray(self.map.features[node].keypoints, dtype=np.float64).reshape(-1, 2)[i_ref]
        inlier, _ = self._explained_matches(node, T_map_live, q)
        return MatchedPixels(node, live_px.astype(np.float32), kf_px.astype(np.float32), inlier)

    def _prepare(
        self, color: NDArray[np.uint8], depth: NDArray[np.float32] | None, timer: StageTimer
    ) -> tuple[FeatureSet, NDArray[np.float32], NDArray[np.float32]]:
        """Live features and VPR descriptor; the depth image, checked."""
        if depth is None or depth.shape != color.shape[:2]:
            raise ValueError("localization needs a depth image registered to the colour image")
        t0 = self.clock()
        feats = self.extract(color)
        timer.add("extract", t0)
        t0 = self.clock()
        desc = np.asarray(self.describe(color), dtype=np.float32)
        timer.add("vpr", t0)
        return feats, desc, depth

    def _joint(self, node: int, T_init: NDArray[np.float64], q: Query, fallback: list[int],
               min_keyframes: int) -> RefineResult:
        """Joint refinement over `node` and up to `refine.max_keyframes - 1` other keyframes
        (covisible neighbours of `node` by weight first, then `fallback` nodes)."""
        rp = self.params.refine
        others = list(self._neighbours[node])
        others += [n for n in fallback if n != node and n not in others]
        extra = others[: rp.max_keyframes - 1]
        obs = [q.observations(node)]
        if rp.extra_matching == "model":
            obs += [q.observations(o) for o in extra]
        else:
            t0 = self.clock()
            obs += [q.guided_observations(o, T_init) for o in extra]
            q.timer.add("guided_match", t0)
        t0 = self.clock()
        res = refine_pose(T_init, obs, replace(rp, min_keyframes=min(min_keyframes, rp.max_keyframes)))
        q.timer.add("refine", t0)
        return res

    # ---------------------------------------------------------------- GL and LL
    def localize_global(
        self, t_ns: int, color: NDArray[np.uint8], depth: NDArray[np.float32] | None, K: NDArray[np.float64],
        prior_T_map_camera: NDArray[np.float64] | None = None, prior_age_s: float = 0.0,
        recovering: bool = False, region: SearchRegion | None = None, prior_cov: NDArray[np.float64] | None = None,
        prior_travel_m: float | None = None, only: Sequence[int] | None = None,
    ) -> LocalizationResult:
        """VPR top-k + geometric verification; the best accepted candidate wins (after the
        joint refinement / confirmation by a second keyframe, see `LocalizationParams`).
        `recovering` (after tracking was lost) bounds the query's wall time by the LL cost, see
        `gl_budget_ms`; `gl_time_budget_ms` bounds it always.

        With joint refinement on, a candidate that only its own keyframe confirms becomes the
        result's `provisional` pose (most inliers first), or is accepted when it agrees with the
        fused prior `prior_T_map_camera` (`prior_age_s` s and `prior_travel_m` m of odometry since
        its last fix; only while fresh, see `_fresh`) within the prior gate (`prior_cov`: fusion's
        3x3 camera position covariance, m^2, map frame, see `_gate_toward`). `region` (an initial
        pose) restricts the candidates to keyframes within it before the top-k cut. An accepted
        pose outside a given prior's gate is measured against the prior's place
        (`_against_the_priors_place`). `only`: verify these nodes, in this order, instead of
        the retrieved candidates. A query every pass refused is looked at again at full
        resolution where that is configured (`_look_again`)."""
        prior = None if prior_T_map_camera is None else check_rigid(prior_T_map_camera, "prior T_map_camera",
                                                                      atol=1e-4)
        timer = StageTimer(self.clock)
        t_all = self.clock()
        q, desc, sims, order, front_ms = self._retrieve(color, depth, K, region, timer, t_all, only)

        def verify() -> LocalizationResult:
            if self.params.refine.enabled:
                fused = (prior, prior_age_s, prior_travel_m, prior_cov)
                return self._verify_refined(t_ns, q, sims, order, fused, recovering, timer, t_all, front_ms)
            return self._verify_confirmed(t_ns, q, sims, order, timer, t_all)

        res = with_second_passes(self._under(verify, q), self.params, q.timer, self._map_has_depth)
        if not res.accepted and self.second_look is not None:
            res = self._look_again(res, (color, depth, K), (prior, prior_age_s, prior_travel_m, prior_cov))
        if not res.accepted or prior is None or not self.params.gl_check_prior_place:
            return res
        return self._against_the_priors_place(res, q, desc, (prior, prior_age_s, prior_travel_m, prior_cov), t_all)

    def _look_again(
        self, res: LocalizationResult, frame: tuple[NDArray[np.uint8], NDArray[np.float32] | None, NDArray[np.float64]],
        prior_state: tuple[NDArray[np.float64] | None, float, float | None, NDArray[np.float64] | None],
        local_fused: bool | None = None,
    ) -> LocalizationResult:
        """The refused GL (or LL: `local_fused` not None, see `SecondLookFn`) result `res` after
        the second look (`self.second_look`) at the candidates `passes.second_look_nodes` picks
        from its attempts (`frame`: colour, depth, K; `prior_state`: the prior, its age in s, odometry
        travel in m, position covariance): its result where it accepts, else `res`; either way
        with both looks' attempts and time ("second_look" ms, in "total")."""
        p = self.params
        nodes = second_look_nodes(res.attempts, p.second_look_candidates, p.second_look_from_inliers)
        if not nodes or self.second_look is None:
            return res
        prior, age_s, travel_m, cov = prior_state
        look = self.second_look(res.t_ns, *frame, nodes, prior, age_s, prior_cov=cov, prior_travel_m=travel_m,
                                local_fused=local_fused)
        if look is None:
            return res
        ms = dict(res.timings_ms)
        ms["second_look"] = look.timings_ms.get("total", 0.0)
        ms["total"] = ms.get("total", 0.0) + ms["second_look"]
        attempts = res.attempts + look.attempts
        if look.accepted:
            return replace(look, attempts=attempts, timings_ms=ms, stop_reason=(
                f"looked at again at full resolution (nodes {nodes}): {look.stop_reason}; first look: "
                f"{res.stop_reason}"))
        return replace(res, attempts=attempts, timings_ms=ms, stop_reason=(
            f"{res.stop_reason}; looked at again at full resolution (nodes {nodes}): {look.reason}"))

    def _against_the_priors_place(
        self, res: LocalizationResult, q: Query, desc: NDArray[np.float32],
        fused: tuple[NDArray[np.float64], float, float | None, NDArray[np.float64] | None], t_all: float,
    ) -> LocalizationResult:
        """The accepted GL result `res` measured against the fused prior (`fused`: its pose, age
        in s, odometry travel in m, position covariance): where the GL pose lies outside the
        prior's gate, LL's candidates at the prior are verified on the same query; a pose they
        give inside that gate (after LL's joint check) is the result instead, since the images
        verify both places and only the odometry tells them apart (a repeating corridor). Else
        `res`, its stop reason saying that the prior's place did not verify."""
        prior, age_s, travel_m, cov = fused
        assert res.T_map_camera is not None
        growth = self._prior_growth_m(age_s, True, travel_m)
        gate_m = self._gate_m(growth, fused=True)
        if self._within_gate(res.T_map_camera, prior, gate_m, cov):
            return res
        dt, _ = relative_pose_error(res.T_map_camera, prior)
        q.timer.ms.pop("total", None)  # the whole query's, measured again below
        local = self._local_attempts(res.t_ns, q, self.local_candidates(prior, desc), prior, (growth, gate_m, cov),
                                     q.timer, t_all)
        why = f"GL's pose (node {res.ref_node}) lay {dt:.2f} m from the prior, outside its gate"
        attempts = res.attempts + local.attempts
        if not local.accepted:
            return replace(res, attempts=attempts, timings_ms=q.timer.ms,
                           stop_reason=f"{res.stop_reason}; {why}; the prior's place did not verify")
        return replace(local, attempts=attempts, stop_reason=f"{why}; the prior's place verified (node "
                       f"{local.ref_node}): the images verify both, the odometry tells them apart")

    def _under(self, verify: Callable[[], LocalizationResult], q: Query) -> VerifyFn:
        """`verify` as a pass under given parameters: the localizer and the query read them
        while it runs, its own restored after."""
        def run(params: LocalizationParams) -> LocalizationResult:
            p = self.params
            self.params = q.params = params
            try:
                return verify()
            finally:
                self.params = q.params = p
        return run

    def _retrieve(self, color: NDArray[np.uint8], depth: NDArray[np.float32] | None, K: NDArray[np.float64],
                  region: SearchRegion | None, timer: StageTimer, t_all: float, only: Sequence[int] | None = None
                  ) -> tuple[Query, NDArray[np.float32], NDArray[np.float32], NDArray[np.int64], float]:
        """Retrieval: the query's features, its (D,) VPR descriptor and (N,) similarity to every
        keyframe, the candidate keyframes in VPR order (`only` instead, where given) and the
        front end's milliseconds."""
        q, desc = self._query(color, depth, K, timer)
        front_ms = (self.clock() - t_all) * 1e3  # feature extraction and VPR, as in an LL query
        sims = self.map.vpr @ desc
        if only is not None:
            return q, desc, sims, np.asarray(list(only), dtype=np.int64), front_ms
        return q, desc, sims, self.global_candidates(sims, q, region), front_ms

    def _verify_refined(self, t_ns: int, q: Query, sims: NDArray[np.float32], order: NDArray[np.int64],
                        fused: tuple[NDArray[np.float64] | None, float, float | None, NDArray[np.float64] | None],
                        recovering: bool, timer: StageTimer, t_all: float, front_ms: float) -> LocalizationResult:
        """Verification with joint refinement: candidates in VPR order, each verified and jointly
        refined at once; the first that passes the joint check wins (then the opt-in
        distinctiveness test), or one that agrees with a fresh prior; the time budget stops the
        search (bounded cost). `fused`: the fused prior, its age (s), odometry travel (m) and position covariance."""
        prior, prior_age_s, prior_travel_m, prior_cov = fused
        attempts: list[CandidateAttempt] = []
        best: tuple[int, PnpResult, RefineResult | None] | None = None
        reason = "not localized: no VPR candidate verified"
        stop = f"all {len(order)} VPR candidates tried"
        provisional: ProvisionalPose | None = None
        growth = self._prior_growth_m(prior_age_s, True, prior_travel_m)
        evidence: list[VerifiedPose] = []  # every candidate's PnP pose, for the distinctiveness test
        trusted = prior is not None and self._fresh(growth)
        gl_params = self._gl_params(trusted)
        floor = gl_params.pnp.min_inliers  # a weaker candidate passes only pooled (see `passes.pooled_short`)
        budget = self.params.gl_time_budget_ms
        candidates_ms = 0.0  # verification time (match, PnP, joint refinement) of the candidates so far
        for k, node in enumerate(int(n) for n in order):
            spent = (self.clock() - t_all) * 1e3
            ahead = candidates_ms / max(k, 1)  # this query's mean cost per candidate so far
            if k == 1 and recovering:
                budget = self.gl_budget_ms(nominal_ll_ms=front_ms + candidates_ms)
            if k > 0 and budget > 0 and spent + ahead > budget:
                stop = (f"time budget ({budget:.0f} ms) would be overrun: {spent:.0f} ms spent + "
                        f"{ahead:.0f} ms per candidate, after {k} of {len(order)} candidates")
                break
            t_cand = self.clock()
            res, att = self._verify_global(node, q, float(sims[node]), evidence, pooled(gl_params))
            if res is None or not res.accepted or res.T_target_source is None:
                attempts.append(att)
                candidates_ms += (self.clock() - t_cand) * 1e3
                continue
            T = self.map.T_map_camera[node] @ res.T_target_source
            weak = res.n_inliers < floor
            joint = self._joint(node, T, q, [int(n) for n in order],
                                self.params.refine.min_keyframes if self.params.gl_confirm or weak else 1)
            candidates_ms += (self.clock() - t_cand) * 1e3
            short = pooled_short(res, joint, floor, self.params.refine.min_keyframes)
            if short:
                attempts.append(replace(att, reason=short, refusal=Refusal.INLIERS))
                continue
            if joint.accepted:
                attempts.append(att)
                best = (node, res, joint)
                stop = f"candidate {k + 1} of {len(order)} passed the joint check"
                amb = "" if trusted else self._ambiguity(node, res, joint, q, order[k + 1:], sims, evidence)
                if amb:
                    best, provisional, reason = None, None, f"not localized: {amb}"
                    stop = f"{stop}; {amb}"
                break
            single = self._single_keyframe(node, joint)
            if single is not None and self._agrees_with_prior(single, prior, growth, prior_cov):
                attempts.append(CandidateAttempt(node, att.similarity, att.matches, att.inliers,
                                                 "one keyframe only; agrees with the prior", Refusal.NONE))
                best = (node, res, replace(joint, accepted=True, reason="ok"))
                stop = f"candidate {k + 1} of {len(order)}: one keyframe, agrees with the prior"
                break
            if single is not None and (provisional is None or single.n_inliers > provisional.n_inliers):
                provisional = single
            attempts.append(CandidateAttempt(node, att.similarity, att.matches, att.inliers,
                                             f"joint refinement rejected: {joint.reason}"))
            reason = f"not localized: no verified pose was confirmed by a second keyframe (last: node {node})"
        timer.add("total", t_all)
        out = replace(self._result(t_ns, "global", best, attempts, timer, reason, q), stop_reason=stop,
                      candidates=tuple(int(n) for n in order))
        return out if out.accepted or provisional is None else replace(out, provisional=provisional)

    def _agrees_with_prior(self, single: ProvisionalPose, prior: NDArray[np.float64] | None, growth: float,
                           cov: NDArray[np.float64] | None) -> bool:
        """Whether a one-keyframe pose lies within the gate of a fresh fused prior (the opt-in
        acceptance of a pose only its own keyframe confirms)."""
        return prior is not None and self._fresh(growth) and self._within_gate(
            single.T_map_camera, prior, self._gate_m(growth, fused=True), cov)

    def _verify_confirmed(self, t_ns: int, q: Query, sims: NDArray[np.float32], order: NDArray[np.int64],
                          timer: StageTimer, t_all: float) -> LocalizationResult:
        """Verification without joint refinement: every candidate verified (or up to the early
        accept), then the one with most inliers that a second keyframe confirms wins."""
        attempts: list[CandidateAttempt] = []
        best: tuple[int, PnpResult, RefineResult | None] | None = None
        reason = "not localized: no VPR candidate verified"
        verified: list[tuple[int, PnpResult]] = []
        for node in order:
            res, att = self._verify_global(int(node), q, float(sims[node]))
            attempts.append(att)
            if res is not None and res.accepted:
                verified.append((int(node), res))
                if 0 < self.params.gl_early_accept_inliers <= res.n_inliers:
                    break
        for node, res in sorted(verified, key=lambda v: -v[1].n_inliers):
            assert res.T_target_source is not None
            T = self.map.T_map_camera[node] @ res.T_target_source
            if not self.params.gl_confirm:
                best = (node, res, None)
                break
            n_ok = self._confirmed(node, T, q, [int(n) for n in order])
            if n_ok >= self.params.confirm_min_inliers:
                best = (node, res, None)
                break
            why = f"unconfirmed ({n_ok} consistent matches with a second keyframe)"
            reason = f"not localized: no verified pose was confirmed by a second keyframe (last: node {node})"
            attempts.append(CandidateAttempt(node, float(sims[node]), res.n_matches, res.n_inliers, why))
        timer.add("total", t_all)
        return self._result(t_ns, "global", best, attempts, timer, reason, q)

    def global_candidates(self, sims: NDArray[np.float32], q: Query,
                          region: SearchRegion | None = None) -> NDArray[np.int64]:
        """The map nodes GL verifies, in order (node ids, at most `gl_top_k`): the
        `gl_rerank_depth` most similar by place descriptor (`sims`, (N,) per node) among the
        keyframes within `region` (an initial pose) where one is given, re-ordered by local
        matches (`_rerank`), the first `gl_top_k` of them. The one place where GL's candidate
        list is made: a filter on the candidates belongs here."""
        p = self.params
        ranked = np.argsort(-sims, kind="stable")
        if region is not None:
            ranked = nodes_within(ranked, self.map.positions, region)
        shortlist = ranked[: max(p.gl_top_k, p.gl_rerank_depth if p.gl_rerank else 0)]
        return self._rerank(shortlist, q)[: p.gl_top_k]

    def _rerank(self, order: NDArray[np.int64], q: Query) -> NDArray[np.int64]:
        """The VPR candidates `order` (best first) re-ordered by their mutual-nearest-neighbour
        count with the live descriptors (`gl_rerank`), VPR order breaking ties."""
        if not self.params.gl_rerank or len(order) < 2:
            return order
        t0 = self.clock()
        live = np.asarray(q.feats.descriptors)
        q.rerank_pairs = {int(n): mutual_nn_pairs(live, self.map.features[int(n)].descriptors,
                                                  self.params.gl_rerank_min_similarity) for n in order}
        q.rerank_counts = {n: len(pairs[0]) for n, pairs in q.rerank_pairs.items()}
        counts = [q.rerank_counts[int(n)] for n in order]
        q.timer.add("rerank", t0)
        return order[np.argsort(-np.asarray(counts), kind="stable")]

    def _gl_params(self, trusted_prior: bool) -> LocalizationParams:
        """The parameters GL verifies its candidates with: PnP's inlier floor lowered to
        `gl_distinct_min_inliers` where the distinctiveness test will judge the pose (on, and
        no trusted prior), else the localizer's own."""
        p = self.params
        if p.gl_distinct_ratio <= 0 or p.gl_distinct_min_inliers <= 0 or trusted_prior:
            return p
        return replace(p, pnp=replace(p.pnp, min_inliers=p.gl_distinct_min_inliers))

    def _ambiguity(self, winner: int, res: PnpResult, joint: RefineResult, q: Query,
                   later: NDArray[np.int64], sims: NDArray[np.float32], verified: list[VerifiedPose]) -> str:
        """The distinctiveness test of the GL pose `joint.T_map_camera` verified through `winner`
        (`res` its PnP) without a trusted prior: the refusal reason when a candidate at another
        place has at least 1/`gl_distinct_ratio` of its inliers, else ''. Judged on `verified`
        (the candidates verified so far), then on the `rivals_to_verify` among the `later`
        candidates one at a time (appended to `verified`), stopping once a rival decides."""
        p = self.params
        if p.gl_distinct_ratio <= 0:
            return ""
        t0 = self.clock()
        more = rivals_to_verify([int(n) for n in later], q.rerank_counts, winner, p.gl_distinct_ratio,
                                p.gl_distinct_max_rivals)
        amb = ""
        for node in [None, *more]:
            if node is not None and not (p.gl_distinct_screen and self._same_place_unmatched(node, q, joint)):
                self._verify_global(node, q, float(sims[node]), verified)
            rival = strongest_rival(joint.T_map_camera, [v for v in verified if v.node != winner], p.gl_distinct_m,
                                    p.gl_distinct_deg)
            amb = ambiguity(winner, res.n_inliers, rival, p.gl_distinct_ratio)
            if amb:
                break
        q.timer.add("distinct", t0)
        return amb

    def _same_place_unmatched(self, node: int, q: Query, joint: RefineResult) -> bool:
        """Whether PnP on `node`'s re-ranking matches (mutual nearest neighbours, no model run)
        puts the live camera at the joint pose's place (`same_place`); False where it cannot
        tell (no such matches, no pose): the candidate is then verified with the matcher."""
        pairs = q.rerank_pairs.get(node)
        if pairs is None:
            return False
        t0 = self.clock()
        res, _, _, _ = relative_pose(q.feats, q.depth, q.K, self.map.features[node], self.map.K[node],
                                     lambda a, b: pairs, self.params, None, self.map.keypoint_depth(node))
        q.timer.add("distinct_screen", t0)
        if res is None or not res.accepted or res.T_target_source is None:
            return False
        p = self.params
        return same_place(self.map.T_map_camera[node] @ res.T_target_source, joint.T_map_camera, p.gl_distinct_m,
                          p.gl_distinct_deg)

    def gl_budget_ms(self, nominal_ll_ms: float = float("inf")) -> float:
        """The wall-time bound (ms) on a GL query while recovering: `lost_cost_ratio` x the cost
        of an LL query, the median wall time of the last `LL_COST_WINDOW` LL queries or
        `nominal_ll_ms` (the GL query's own feature extraction and VPR plus one candidate's
        verification: what an LL query that runs the matcher once costs) where lower or where
        no LL query has run; and `gl_time_budget_ms` when set (the smaller bound); 0 = none."""
        bounds = [b for b in (self.params.gl_time_budget_ms,) if b > 0]
        ll = min(float(np.median(self.ll_wall_ms)) if self.ll_wall_ms else float("inf"), nominal_ll_ms)
        if self.params.lost_cost_ratio > 0 and np.isfinite(ll):
            bounds.append(self.params.lost_cost_ratio * ll)
        return min(bounds) if bounds else 0.0

    def _confirmed(self, node: int, T_map_live: NDArray[np.float64], q: Query, fallback: list[int]) -> int:
        """Best count of matches explained by the pose over up to `confirm_max_nodes` other
        keyframes (covisible neighbours of `node` by weight first, then `fallback` nodes).
        The old, single-keyframe behaviour (`refine.enabled: false`)."""
        others = list(self._neighbours[node])
        others += [n for n in fallback if n != node and n not in others]
        t0 = self.clock()
        best = 0
        for other in others[: self.params.confirm_max_nodes]:
            best = max(best, self._consistent(T_map_live, q, other))
            if best >= self.params.confirm_min_inliers:
                break
        q.timer.add("confirm", t0)
        return best

    def confirm(
        self, T_map_live: NDArray[np.float64], live_feats: FeatureSet, depth: NDArray[np.float32],
        K: NDArray[np.float64], node: int,
    ) -> int:
        """Matches with `node` that the pose `T_map_live` explains (reprojection within the PnP threshold)."""
        q = Query(self.map, self.params, self.match, live_feats, depth, K, StageTimer(self.clock))
        return self._consistent(T_map_live, q, node)

    def _consistent(self, T_map_live: NDArray[np.float64], q: Query, node: int) -> int:
        ob = q.observations(node)
        if len(ob.points_live) == 0:
            return 0
        T_node_live = np.linalg.inv(self.map.T_map_camera[node]) @ T_map_live
        pc = ob.points_live @ T_node_live[:3, :3].T + T_node_live[:3, 3]
        front = pc[:, 2] > 1e-3
        Kn = self.map.K[node]
        proj = (pc[front, :2] / pc[front, 2:3]) * [Kn[0, 0], Kn[1, 1]] + [Kn[0, 2], Kn[1, 2]]
        err = np.linalg.norm(proj - ob.pixels[front], axis=1)
        return int(np.count_nonzero(err <= self.params.pnp.reprojection_px))

    def local_candidates(self, prior: NDArray[np.float64], desc: NDArray[np.float32]) -> list[tuple[int, float]]:
        """(node, similarity) candidates for a prior pose, best first; empty if none is near.

        The nearest node (none if farther than `gl_trigger_distance_m`), its covisible
        neighbours and every node within `candidate_radius_m` that faces within
        `max_view_angle_deg` of the prior, ranked by VPR similarity; looked up in the map's
        KD-tree node index (`TopoMap.node_index`), so the cost does not grow with the map."""
        p = self.params
        return self.map.node_index.local_candidates(
            prior, desc, self.map.vpr, self.map.T_map_camera, self._neighbours, p.candidate_radius_m,
            p.gl_trigger_distance_m, p.max_view_angle_deg, p.ll_max_candidates)

    def localize_local(
        self, t_ns: int, color: NDArray[np.uint8], depth: NDArray[np.float32] | None, K: NDArray[np.float64],
        prior_T_map_camera: NDArray[np.float64], prior_age_s: float = 0.0, fused_prior: bool = False,
        prior_cov: NDArray[np.float64] | None = None, prior_travel_m: float | None = None,
        only: Sequence[int] | None = None,
    ) -> LocalizationResult:
        """LL from a prior pose; candidates tried in similarity order until one is accepted
        (`only`: these nodes, in this order, instead of the prior's candidates).

        A candidate's pose must also pass the prior gate (see `LocalizationParams`), which grows
        with `prior_age_s` at the fused-prior rate (`fused_prior`: odometry since the last fix,
        no more than its drift over `prior_travel_m`) or at the robot's top speed (the last VLoc
        pose); a fused prior's `prior_cov` (3x3 position covariance, m^2, map frame) narrows it
        where fusion knows better (`_gate_toward`). A query every pass refused is looked at
        again at full resolution where that is configured (`second_look_local`, `_look_again`)."""
        prior = check_rigid(prior_T_map_camera, "prior T_map_camera", atol=1e-4)
        timer = StageTimer(self.clock)
        t_all = self.clock()
        q, desc = self._query(color, depth, K, timer)
        if only is None:
            cands = self.local_candidates(prior, desc)
        else:
            sims = self.map.vpr @ desc
            cands = [(int(n), float(sims[int(n)])) for n in only]
        growth = self._prior_growth_m(prior_age_s, fused_prior, prior_travel_m)
        gate_m = self._gate_m(growth, fused_prior)
        verify = self._under(
            lambda: self._local_attempts(t_ns, q, cands, prior, (growth, gate_m, prior_cov), timer, t_all), q)
        res = with_second_passes(verify, self.params, q.timer, self._map_has_depth, allowed=self._fresh(growth))
        if not res.accepted and self.second_look is not None and self.params.second_look_local:
            res = self._look_again(res, (color, depth, K), (prior, prior_age_s, prior_travel_m, prior_cov),
                                   local_fused=fused_prior)
        return res

    def _local_attempts(self, t_ns: int, q: Query, cands: list[tuple[int, float]], prior: NDArray[np.float64],
                        gate: tuple[float, float, NDArray[np.float64] | None], timer: StageTimer,
                        t_all: float) -> LocalizationResult:
        """LL's candidates `cands` (node, similarity) tried in order until one passes the prior
        gate (`gate`: the prior's growth and radius in m, its position covariance, see
        `_gate_toward`) and the joint refinement or confirmation (see `localize_local`)."""
        growth, gate_m, cov = gate
        attempts: list[CandidateAttempt] = []
        best: tuple[int, PnpResult, RefineResult | None] | None = None
        guided_first = self.params.ll_guided_min_matches > 0 and self._fresh(growth)
        floor = self.params.pnp.min_inliers  # a weaker candidate passes only pooled (see `passes.pooled_short`)
        for node, sim in cands:
            res, att = self._verify_local(node, q, sim, prior if guided_first else None, pooled(self.params))
            if res is not None and res.accepted and res.T_target_source is not None:
                T = self.map.T_map_camera[node] @ res.T_target_source
                dt, dr = relative_pose_error(T, prior)
                radius = self._gate_toward(T, prior, gate_m, cov)
                if dt > radius or dr > self.params.prior_gate_deg:
                    att = CandidateAttempt(node, sim, att.matches, att.inliers,
                                           f"inconsistent with the prior ({dt:.2f} m > {radius:.2f} m or "
                                           f"{dr:.0f} deg)")
                    attempts.append(att)
                    continue
                weak = res.n_inliers < floor
                close = (dt <= self.params.confirm_skip_within_m and dr <= self.params.confirm_skip_within_deg
                         and self._fresh(growth) and not weak)
                joint: RefineResult | None = None
                if self.params.refine.enabled:
                    need = self.params.refine.min_keyframes if (self.params.ll_confirm and not close) or weak else 1
                    joint = self._joint(node, T, q, [n for n, _ in cands], need)
                    if not joint.accepted and not weak:  # a weak one is refused below, saying so
                        attempts.append(CandidateAttempt(node, sim, att.matches, att.inliers,
                                                         f"joint refinement rejected: {joint.reason}"))
                        continue
                elif self.params.ll_confirm and not close:
                    n_ok = self._confirmed(node, T, q, [n for n, _ in cands])
                    if n_ok < self.params.confirm_min_inliers:
                        why = f"unconfirmed ({n_ok} consistent matches with a second keyframe)"
                        attempts.append(CandidateAttempt(node, sim, att.matches, att.inliers, why))
                        continue
                short = pooled_short(res, joint, floor, self.params.refine.min_keyframes)
                if short:
                    attempts.append(replace(att, reason=short, refusal=Refusal.INLIERS))
                    continue
                attempts.append(att)
                best = (node, res, joint)
                break
            attempts.append(att)
        timer.add("total", t_all)
        reason = "no map node near the prior" if not cands else "not localized: no candidate verified"
        return self._result(t_ns, "local", best, attempts, timer, reason, q)

    # ---------------------------------------------------------------- state machine
    def _hold_unless_repeated(self, res: LocalizationResult, prior_T_map_camera: NDArray[np.float64],
                              prior_age_s: float, prior_travel_m: float | None,
                              prior_cov: NDArray[np.float64] | None) -> LocalizationResult:
        """An accepted result (GL, or LL with a fused prior) as it is when it lies inside the
        gate of a fresh fused prior (see `_fresh`) or repeats the held pose (see
        `LocalizationParams.repeat_within_s`); otherwise it is held and the result says so
        (not accepted)."""
        p = self.params
        if p.repeat_within_s <= 0 or res.T_map_camera is None:
            return res
        T = np.asarray(res.T_map_camera, np.float64)
        prior = np.asarray(prior_T_map_camera, np.float64)
        growth = self._prior_growth_m(prior_age_s, True, prior_travel_m)
        gate = self._gate_toward(T, prior, self._gate_m(growth, fused=True), prior_cov)
        dt, dr = relative_pose_error(T, prior)
        inside, fresh = dt <= gate and dr <= p.prior_gate_deg, self._fresh(growth)
        if inside and fresh:
            self.held = None
            return res
        held = self.held
        if held is not None:
            dt_s = (res.t_ns - held.t_ns) * 1e-9
            # the window includes its end up to the clock's jitter: frames taken every 1.0 s
            # of a simulated or camera clock came 5.000000025 s apart, and a repeat 5 frames on
            # was refused (loop world navigation, seed 1: held poses right to 0.2 m, the robot
            # drove on odometry into the corridor wall)
            # the prior's motion since then (odometry): where the held pose is now
            carried = np.linalg.inv(held.prior_T_map_camera) @ prior
            # a robot that stayed put may wait any time for the repeat (GL takes 20 s on a loaded
            # computer); the odometry's drift grows with its motion then, not with the time
            still = float(np.linalg.norm(carried[:3, 3])) <= p.repeat_within_m
            in_window = 0 < dt_s <= p.repeat_within_s + _CLOCK_JITTER_S
            if in_window or (dt_s > 0 and still):
                expected = held.T_map_camera @ carried
                et, er = relative_pose_error(T, expected)
                tol = p.prior_gate_fused_m + p.prior_gate_rate_fused_mps * min(dt_s, p.repeat_within_s)
                if et <= tol and er <= p.repeat_deg:
                    self.held = None
                    return replace(res, stop_reason=f"{res.stop_reason}; repeats the pose held {dt_s:.2f} s "
                                   f"before ({et:.2f} m, {er:.1f} deg), {gate:.2f} m gate of the prior")
            # in a repeating place the copy outside the gate and the pose inside it come by turns: the
            # copy must not displace the held pose that agrees with the prior, or neither is ever repeated
            if in_window and held.inside_gate and not inside:
                return _refused(res, f"not localized: {dt:.2f} m / {dr:.0f} deg from the prior, outside its gate "
                                     f"({gate:.2f} m), while a pose inside it held {dt_s:.2f} s before awaits "
                                     "its repeat")
        self.held = HeldPose(res.t_ns, T, prior, inside)
        why = (f"{dt:.2f} m / {dr:.0f} deg from the prior, outside its gate ({gate:.2f} m, {p.prior_gate_deg:g} deg)"
               if not inside else f"the prior is {prior_age_s:.1f} s past its last fix"
               + ("" if prior_travel_m is None else f" and {prior_travel_m:.1f} m of odometry")
               + ", too old to confirm it")
        return _refused(res, f"not localized: {'GL' if res.mode == 'global' else 'LL'} pose held until a later frame "
                             f"repeats it ({why})")

    def _go(self, t_ns: int, to: TrackingState, reason: str) -> None:
        if to != self.state:
            self.transitions.append(Transition(t_ns, self.state, to, reason))
            self.state = to

    def process(
        self, t_ns: int, color: NDArray[np.uint8], depth: NDArray[np.float32] | None, K: NDArray[np.float64],
        prior_T_map_camera: NDArray[np.float64] | None = None, prior_age_s: float = 0.0,
        region: SearchRegion | None = None, prior_cov: NDArray[np.float64] | None = None,
        prior_travel_m: float | None = None,
    ) -> LocalizationResult:
        """One frame through the state machine. The prior (e.g. the fused pose at `t_ns`,
        `prior_age_s` old, `prior_travel_m` metres of odometry since its fix, `prior_cov` its 3x3
        camera position covariance in m^2, map frame) is used in TRACKING; without one, the last
        accepted VLoc pose is the prior. In GLOBAL state it can accept a single-keyframe GL pose
        that agrees with it.
        `region` (an initial pose given by the user): GL within it, whatever the state, the prior ignored."""
        if prior_cov is not None:
            prior_cov = np.asarray(prior_cov, np.float64)
            if prior_cov.shape != (3, 3) or not np.all(np.isfinite(prior_cov)):
                raise ValueError(f"prior_cov must be a finite 3x3 covariance (m^2), got shape {prior_cov.shape}")
        if region is not None:
            self._go(t_ns, TrackingState.GLOBAL, "initial pose given")
            prior_T_map_camera = None
        if self.state in (TrackingState.INIT, TrackingState.LOST):
            why = "start-up" if self.state == TrackingState.INIT else "recover from LOST"
            self._go(t_ns, TrackingState.GLOBAL, why)
        if self.state == TrackingState.TRACKING:
            fused = prior_T_map_camera is not None
            if prior_T_map_camera is not None:
                prior, age = prior_T_map_camera, prior_age_s
            else:
                assert self.last_pose is not None
                prior, age = self.last_pose, (t_ns - self.last_pose_t_ns) * 1e-9
            res = self.localize_local(t_ns, color, depth, K, prior, prior_age_s=age, fused_prior=fused,
                                      prior_cov=prior_cov if fused else None,
                                      prior_travel_m=prior_travel_m if fused else None)
            if "total" in res.timings_ms:
                self.ll_wall_ms.append(res.timings_ms["total"])
            if res.accepted and fused:  # a stale fused prior cannot confirm an LL pose either
                res = self._hold_unless_repeated(res, prior, age, prior_travel_m, prior_cov)
            if res.accepted:
                self.failures = 0
                self.last_pose, self.last_pose_t_ns = res.T_map_camera, t_ns
                return res
            if res.reason == "no map node near the prior":
                self._go(t_ns, TrackingState.GLOBAL, "prior far from every map node")
            else:
                self.failures += 1
                if self.failures >= self.params.ll_failures_before_lost:
                    self._go(t_ns, TrackingState.LOST, f"{self.failures} consecutive LL failures")
                    self.failures = 0
                return res
        res = self.localize_global(t_ns, color, depth, K, prior_T_map_camera, prior_age_s,  # recovering: it has tracked
                                   recovering=self.last_pose is not None, region=region, prior_cov=prior_cov,
                                   prior_travel_m=prior_travel_m)
        if res.accepted and prior_T_map_camera is not None:
            res = self._hold_unless_repeated(res, prior_T_map_camera, prior_age_s, prior_travel_m, prior_cov)
        if res.accepted:
            self.failures = 0
            self.last_pose, self.last_pose_t_ns = res.T_map_camera, t_ns
            self._go(t_ns, TrackingState.TRACKING, f"GL verified node {res.ref_node} ({res.n_inliers} inliers)")
        return res
