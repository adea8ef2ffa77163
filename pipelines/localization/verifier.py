"""The candidate verifier: one map keyframe checked against the live query, the checks in order.

GL and LL (`global_search`, `local_search`) differ in which candidates they try, in the checks
they run and in what they do with the verdict; both run a candidate through their ordered list
of checks here (`CandidateVerifier.run`): PnP + RANSAC into the keyframe (`checks.pnp`), the
support check (GL, `checks.support`) or the prior gate (LL, `checks.prior_gate`), the joint
refinement over the keyframe and its covisible neighbours (`checks.joint`) and the pooled inlier
count of a weak candidate (`checks.pooled`). The parameters of a verification pass are the
query's (`Query.under`): nothing here holds parameters of its own.

Pose chain: PnP gives `T_node_live` (live camera -> map keyframe camera), hence
`T_map_live = T_map_node @ T_node_live`. The covariance is that of a right (camera-frame)
perturbation of `T_map_live`, order (tx, ty, tz, rx, ry, rz), see `pipelines.pnp`.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from litevloc.base.geometry import backproject_pixels
from litevloc.base.params.localization import LocalizationParams
from litevloc.pipelines.localization.query import Clock, MatchFn, Query, StageTimer, relative_pose, reprojects
from litevloc.pipelines.localization.refine import RefineResult, refine_pose
from litevloc.pipelines.localization.refusals import QueryRefusal, refusal_text
from litevloc.pipelines.localization.results import CandidateAttempt, LocalizationResult, MatchedPixels
from litevloc.pipelines.pnp import PnpResult
from litevloc.pipelines.topomap.types import FeatureSet, TopoMap

ExtractFn = Callable[[NDArray[np.uint8]], FeatureSet]
DescribeFn = Callable[[NDArray[np.uint8]], NDArray[np.float32]]
Best = tuple[int, PnpResult, RefineResult]  # the accepted candidate: node, its PnP, its joint refinement


@dataclass
class Candidate:
    """One map keyframe under verification, filled in by the checks in order: PnP's result, its
    attempt record and its pose `T_map_camera` (4x4), then the joint refinement."""

    node: int
    similarity: float
    res: PnpResult | None = None
    attempt: CandidateAttempt | None = None
    T_map_camera: NDArray[np.float64] | None = None
    joint: RefineResult | None = None


class Check(Protocol):
    """One check of a candidate under the query's parameters: None when it passes (it may fill
    in the candidate), else the refused attempt, saying why."""

    def __call__(self, c: Candidate, q: Query) -> CandidateAttempt | None: ...


class CandidateVerifier:
    """Verification of map keyframes against one live frame, with injected model callables (no
    I/O, no threads); `clock` times the stages (see `StageTimer`)."""

    def __init__(self, topomap: TopoMap, extract: ExtractFn, describe: DescribeFn, match: MatchFn,
                 clock: Clock = time.perf_counter) -> None:
        self.map = topomap
        self.extract, self.describe, self.match, self.clock = extract, describe, match, clock
        # Covisible neighbours of each node, strongest edge first (computed once, used per query).
        self.neighbours = topomap.covisibility_lists
        self.map_has_depth = topomap.n_nodes > 0 and topomap.keypoint_depth(0) is not None

    def query(self, color: NDArray[np.uint8], depth: NDArray[np.float32] | None, K: NDArray[np.float64],
              params: LocalizationParams, timer: StageTimer) -> tuple[Query, NDArray[np.float32]]:
        """The live frame as a `Query` under `params` and its (D,) VPR descriptor; ValueError
        without a depth image registered to the colour image."""
        if depth is None or depth.shape != color.shape[:2]:
            raise ValueError("localization needs a depth image registered to the colour image")
        t0 = self.clock()
        feats = self.extract(color)
        timer.add("extract", t0)
        t0 = self.clock()
        desc = np.asarray(self.describe(color), dtype=np.float32)
        timer.add("vpr", t0)
        return Query(self.map, params, self.match, feats, depth, K, timer), desc

    def verify(self, node: int, q: Query, similarity: float,
               pnp_params: LocalizationParams | None = None) -> tuple[PnpResult | None, CandidateAttempt]:
        """Match and PnP with `node` (PnP's gates from `pnp_params`, default the query's)."""
        q.matches(node)  # timed as "match" once; relative_pose then reads the cached matches
        res, n_matches, reason, refusal = relative_pose(
            q.feats, q.depth, q.K, self.map.features[node], self.map.K[node], lambda a, b: q.matches(node),
            pnp_params or q.params, q.timer, self.map.keypoint_depth(node), q.pnp_fits,
        )
        return res, CandidateAttempt(node, similarity, n_matches, res.n_inliers if res else 0, reason, refusal)

    def run(self, node: int, similarity: float, q: Query, checks: Sequence[Check]) -> tuple[Candidate,
                                                                                        CandidateAttempt | None]:
        """`node` through `checks` in order, each on what the earlier ones found: the candidate
        and the first refusal (None: every check passed)."""
        c = Candidate(node, similarity)
        for check in checks:
            refusal = check(c, q)
            if refusal is not None:
                return c, refusal
        return c, None

    def explained_matches(self, node: int, T_map_live: NDArray[np.float64],
                          q: Query) -> tuple[NDArray[np.bool_], NDArray[np.float64]]:
        """Which matches with `node` (`q.matches` order) the pose `T_map_live` explains within
        the PnP reprojection threshold, either way: a live point (live depth) reprojected into
        the keyframe, or a keyframe point (map depth) projected into the live image; and each
        match's map-frame point (N, 3), the map's where it explains the match, NaN where none."""
        i_live, i_ref = q.matches(node)
        thr = q.params.pnp.reprojection_px
        T_map_kf = self.map.T_map_camera[node]
        live_pts = q.points()[i_live]  # live camera frame, NaN without depth
        kf_px = np.asarray(self.map.features[node].keypoints, dtype=np.float64).reshape(-1, 2)[i_ref]
        live_px = np.asarray(q.feats.keypoints, dtype=np.float64).reshape(-1, 2)[i_live]
        z_kf = self.map.keypoint_depth(node) if q.params.verify.map_depth else None
        kf_pts = (backproject_pixels(self.map.K[node], kf_px, np.asarray(z_kf, np.float64)[i_ref])
                  if z_kf is not None else np.full((len(i_ref), 3), np.nan))
        with np.errstate(invalid="ignore", divide="ignore"):
            ok_live = reprojects(live_pts, np.linalg.inv(T_map_kf) @ T_map_live, self.map.K[node], kf_px, thr)
            ok_kf = reprojects(kf_pts, np.linalg.inv(T_map_live) @ T_map_kf, q.K, live_px, thr)
        out = np.where(ok_kf[:, None], kf_pts @ T_map_kf[:3, :3].T + T_map_kf[:3, 3],
                       live_pts @ T_map_live[:3, :3].T + T_map_live[:3, 3])
        return ok_live | ok_kf, np.asarray(out, dtype=np.float64)

    def joint(self, node: int, T_init: NDArray[np.float64], q: Query, fallback: list[int],
              min_keyframes: int) -> RefineResult:
        """Joint refinement over `node` and up to `refine.max_keyframes - 1` other keyframes
        (covisible neighbours of `node` by weight first, then `fallback` nodes); accepted where
        `min_keyframes` of them are consistent with the joint pose."""
        rp = q.params.refine
        others = list(self.neighbours[node])
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

    def matched_pixels(self, q: Query | None, node: int, T_map_live: NDArray[np.float64]) -> MatchedPixels | None:
        """The cached matches of `q` with `node`, inliers marked under the accepted pose."""
        if q is None:
            return None
        i_live, i_ref = q.matches(node)
        live_px = np.asarray(q.feats.keypoints, dtype=np.float64).reshape(-1, 2)[i_live]
        kf_px = np.asarray(self.map.features[node].keypoints, dtype=np.float64).reshape(-1, 2)[i_ref]
        inlier, _ = self.explained_matches(node, T_map_live, q)
        return MatchedPixels(node, live_px.astype(np.float32), kf_px.astype(np.float32), inlier)

    def result(self, t_ns: int, mode: str, best: Best | None, attempts: list[CandidateAttempt], timer: StageTimer,
               refusal: tuple[QueryRefusal, str], q: Query | None = None) -> LocalizationResult:
        """The query's result: `best` accepted (its joint pose and covariance), or not localized for
        `refusal` (its kind and text) when None."""
        if best is None:
            return LocalizationResult(t_ns, mode, False, refusal[1], attempts=tuple(attempts), timings_ms=timer.ms,
                                      refusal=refusal[0])
        node, _, joint = best
        n_match = sum(joint.matches_per_keyframe.get(k, 0) for k in joint.inliers_per_keyframe)
        return LocalizationResult(
            t_ns, mode, True, refusal_text(QueryRefusal.NONE), joint.T_map_camera, joint.covariance, node, n_match,
            joint.n_inliers, joint.n_inliers / max(n_match, 1), joint.median_reprojection_px, tuple(attempts),
            timer.ms, tuple(joint.inliers_per_keyframe), matches=self.matched_pixels(q, node, joint.T_map_camera),
        )
