"""One live frame being localized: features, lifted points and per-keyframe matches computed once,
and the two-view relative pose used by GL and LL verification."""

from __future__ import annotations

import copy
import time
from collections.abc import Callable, Sequence

import numpy as np
from numpy.typing import NDArray

from litevloc.base.geometry import backproject_pixels
from litevloc.base.params.localization import LocalizationParams
from litevloc.pipelines.depth_lookup import depth_at
from litevloc.pipelines.localization.refine import KeyframeObservations, guided_matches
from litevloc.pipelines.pnp import PnpFits, PnpResult, Refusal, inverse_result, solve_pnp
from litevloc.pipelines.topomap.types import FeatureSet, TopoMap

MatchFn = Callable[[FeatureSet, FeatureSet], tuple[NDArray[np.int64], NDArray[np.int64]]]
Clock = Callable[[], float]  # monotonic seconds


class StageTimer:
    """Accumulated milliseconds per named stage of one query (extract, vpr, match, lift, pnp, ...),
    read from `clock` (seconds; a benchmark that replays cached model calls passes a clock that
    also counts their recorded time, so time budgets see what a live run would)."""

    def __init__(self, clock: Clock = time.perf_counter) -> None:
        self.ms: dict[str, float] = {}
        self.now = clock

    def add(self, key: str, t0: float) -> None:
        self.ms[key] = self.ms.get(key, 0.0) + (self.now() - t0) * 1e3


def relative_pose(
    live_feats: FeatureSet, live_depth: NDArray[np.float32], K_live: NDArray[np.float64],
    ref_feats: FeatureSet, K_ref: NDArray[np.float64], match: MatchFn, params: LocalizationParams,
    timer: StageTimer | None = None, ref_depth: NDArray[np.float32] | None = None, fits: PnpFits | None = None,
) -> tuple[PnpResult | None, int, str, Refusal]:
    """Pose of the live camera relative to a reference image: `T_ref_live` in the result.

    Matches live vs reference features, lifts the matched live keypoints with the live
    depth (`pipelines.depth_lookup`), solves PnP into the reference image and applies the
    acceptance gates plus the distance gate. With `ref_depth` ((N_ref,) metres at each
    reference keypoint, NaN = none: the map's depth) and `params.verify.map_depth`, it also
    solves PnP from the reference points into the live pixels and keeps the direction with
    more inliers (see `LocalizationParams.verify.map_depth`). `fits`: PnP fits to reuse (see
    `solve_pnp`; a query verified again reuses its fits). Returns (PnpResult or None if
    too few matches, number of matches, reason, which gate refused it: `Refusal.NONE` if none).
    """
    timer = timer if timer is not None else StageTimer()
    add = timer.add
    t0 = timer.now()
    i_live, i_ref = match(live_feats, ref_feats)
    add("match", t0)
    if len(i_live) < max(params.verify.min_matches, params.pnp.min_inliers):  # cheap rejection: PnP cannot pass
        return None, len(i_live), f"too few matches ({len(i_live)})", Refusal.MATCHES
    t0 = timer.now()
    uv = np.asarray(live_feats.keypoints, dtype=np.float64)[i_live]
    kp_ref = np.asarray(ref_feats.keypoints, dtype=np.float64)[i_ref]
    z = depth_at(live_depth, uv, params.depth)
    ok = np.isfinite(z)
    z_ref = (np.asarray(ref_depth, np.float64)[i_ref] if ref_depth is not None and params.verify.map_depth
             else np.full(len(i_ref), np.nan))
    ok_ref = np.isfinite(z_ref) & (z_ref > 0)
    add("lift", t0)
    if max(ok.sum(), ok_ref.sum()) < params.verify.min_matches:
        return None, len(i_live), f"too few matches with depth ({max(ok.sum(), ok_ref.sum())})", Refusal.DEPTH
    t0 = timer.now()
    res: PnpResult | None = None
    if ok.sum() >= params.verify.min_matches:
        pts = backproject_pixels(K_live, uv[ok], z[ok].astype(np.float64))
        res = solve_pnp(pts, kp_ref[ok], K_ref, params.pnp, fits)
    if ok_ref.sum() >= params.verify.min_matches:
        rev = inverse_result(solve_pnp(backproject_pixels(K_ref, kp_ref[ok_ref], z_ref[ok_ref]), uv[ok_ref],
                                       K_live, params.pnp, fits))
        if res is None or (rev.accepted, rev.n_inliers) > (res.accepted, res.n_inliers):
            res = rev
    add("pnp", t0)
    assert res is not None
    if res.accepted and res.T_target_source is not None:
        # The translation of T_ref_live is the live camera centre in the reference frame.
        dist = float(np.linalg.norm(res.T_target_source[:3, 3]))
        if dist > params.verify.max_distance_to_node_m:
            reason = f"pose {dist:.1f} m from its reference node (> {params.verify.max_distance_to_node_m})"
            res = PnpResult(False, reason, res.T_target_source, res.inliers, res.n_matches,
                            res.median_reprojection_px, res.covariance, refusal=Refusal.DISTANCE)
    return res, len(i_live), res.reason, res.refusal


def reprojects(pts: NDArray[np.float64], T_target_source: NDArray[np.float64], K: NDArray[np.float64],
                px: NDArray[np.float64], threshold_px: float) -> NDArray[np.bool_]:
    """(N,) True where source-frame points `pts` (N, 3; NaN rows = no depth), moved into the
    target camera, lie in front of it and project within `threshold_px` of `px` (N, 2)."""
    p = pts @ T_target_source[:3, :3].T + T_target_source[:3, 3]
    uvw = p @ np.asarray(K, dtype=np.float64).T
    err = np.linalg.norm(uvw[:, :2] / uvw[:, 2:3] - px, axis=1)
    return np.asarray(np.isfinite(err) & (p[:, 2] > 0) & (err <= threshold_px), dtype=bool)


class Query:
    """One live frame being localized: its features, depth, the live points lifted once and
    the matches with each keyframe computed at most once (verification, refinement and
    confirmation share them)."""

    def __init__(self, topomap: TopoMap, params: LocalizationParams, match: MatchFn, feats: FeatureSet,
                 depth: NDArray[np.float32], K: NDArray[np.float64], timer: StageTimer) -> None:
        self.map, self.params, self.match = topomap, params, match
        self.feats, self.depth, self.K, self.timer = feats, depth, K, timer
        self._matches: dict[int, tuple[NDArray[np.int64], NDArray[np.int64]]] = {}
        self._model_nodes: frozenset[int] | None = None  # `matching_only`: the nodes the matcher runs for (None: all)
        self._lifted: dict[str, NDArray[np.float64]] = {}  # "points": the lifted live keypoints, once
        self.pnp_fits: PnpFits = {}  # PnP fits, reused when a later pass verifies a keyframe again
        self.rerank_counts: dict[int, int] = {}  # GL: mutual-nearest-neighbour count per re-ranked node
        # GL: those mutual nearest neighbours, (live indices, keyframe indices) per re-ranked node
        self.rerank_pairs: dict[int, tuple[NDArray[np.int64], NDArray[np.int64]]] = {}

    def under(self, params: LocalizationParams) -> Query:
        """This query verified under `params` (a later pass's): the same features, matches, lifted
        points and PnP fits, shared with this one."""
        view = copy.copy(self)
        view.params = params
        return view

    def matching_only(self, nodes: Sequence[int]) -> Query:
        """This query with the matcher model run for `nodes` alone: another keyframe without guided
        matches (`try_guided`) has none. Shares the features, lifted points and PnP fits with this
        one; its matches start as a copy of this one's, so the empty ones it records stay its own."""
        view = copy.copy(self)
        view._matches = dict(self._matches)
        view._model_nodes = frozenset(int(n) for n in nodes)
        return view

    def matches(self, node: int) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        """(live indices, keyframe indices) of the matches with `node`."""
        if node not in self._matches:
            if self._model_nodes is not None and node not in self._model_nodes:
                return np.zeros(0, np.int64), np.zeros(0, np.int64)
            t0 = self.timer.now()
            i_live, i_ref = self.match(self.feats, self.map.features[node])
            self._matches[node] = (np.asarray(i_live, dtype=np.int64), np.asarray(i_ref, dtype=np.int64))
            self.timer.add("match", t0)
        return self._matches[node]

    def points(self) -> NDArray[np.float64]:
        """(N, 3) live keypoints lifted with the live depth (NaN rows where no depth)."""
        if "points" not in self._lifted:
            t0 = self.timer.now()
            uv = np.asarray(self.feats.keypoints, dtype=np.float64).reshape(-1, 2)
            z = depth_at(self.depth, uv, self.params.depth).astype(np.float64)
            pts = np.full((len(uv), 3), np.nan)
            ok = np.isfinite(z)
            pts[ok] = backproject_pixels(self.K, uv[ok], z[ok])
            self._lifted["points"] = pts
            self.timer.add("lift", t0)
        return self._lifted["points"]

    def observations(self, node: int) -> KeyframeObservations:
        """The matches with `node` as refinement input (see `_observations`)."""
        return self._observations(node, *self.matches(node))

    def _observations(self, node: int, i_live: NDArray[np.int64], i_kf: NDArray[np.int64]) -> KeyframeObservations:
        """Matches (live indices, keyframe indices) with `node` as refinement input: those with
        live depth as live points; those without, where the map has depth at the keyframe
        keypoint (and `verify.map_depth`), as keyframe points reprojected into the live image."""
        m = self.map
        pts = self.points()[i_live]
        ok = np.all(np.isfinite(pts), axis=1)
        kp = np.asarray(m.features[node].keypoints, dtype=np.float64)[i_kf]
        z_kf = self._map_depth(node, i_kf)
        if z_kf is None or not self.params.verify.map_depth:
            return KeyframeObservations(node, pts[ok], kp[ok], m.K[node], m.T_map_camera[node],
                                        None if z_kf is None else z_kf[ok])
        rev = ~ok & np.isfinite(z_kf) & (z_kf > 0)
        live_px = np.asarray(self.feats.keypoints, dtype=np.float64).reshape(-1, 2)[i_live[rev]]
        return KeyframeObservations(node, pts[ok], kp[ok], m.K[node], m.T_map_camera[node], z_kf[ok],
                                    backproject_pixels(m.K[node], kp[rev], z_kf[rev]), live_px, self.K)

    def _map_depth(self, node: int, i_kf: NDArray[np.int64]) -> NDArray[np.float64] | None:
        """The map's depth (metres, NaN = none) at keyframe keypoints `i_kf`, None without."""
        z = self.map.keypoint_depth(node)
        return None if z is None else np.asarray(z, np.float64)[i_kf]

    def try_guided(self, node: int, T_map_live: NDArray[np.float64], min_matches: int) -> bool:
        """Match `node` by projecting with `T_map_live` (a fresh prior) instead of the matcher
        (global-mutual rule: `local_search.guided_global_mutual`); the matches are kept (and
        returned by `matches`) only when at least `min_matches`."""
        if node in self._matches:
            return False
        t0 = self.timer.now()
        i_live, i_kf = self._guided(node, T_map_live, self.params.local_search.guided_global_mutual)
        self.timer.add("guided_match", t0)
        if len(i_live) < min_matches:
            return False
        self._matches[node] = (i_live, i_kf)
        return True

    def forget(self, node: int) -> None:
        """Drop `node`'s cached matches (the next `matches` runs the matcher)."""
        self._matches.pop(node, None)

    def _guided(self, node: int, T_map_live: NDArray[np.float64],
                global_mutual: bool | None = None) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        """(live, keyframe) indices of the matches with `node` found by projecting the live
        points with `T_map_live` (no model; `global_mutual`: as for `guided_matches`)."""
        m = self.map
        f = m.features[node]
        return guided_matches(self.points(), self.feats.descriptors, T_map_live, f.keypoints, f.descriptors,
                              m.K[node], m.T_map_camera[node], self.params.refine, global_mutual)

    def guided_observations(self, node: int, T_map_live: NDArray[np.float64]) -> KeyframeObservations:
        """Matches with `node` found by projecting with `T_map_live` (no model): the live points
        into the keyframe, and (`verify.map_depth`) the keyframe's points (map depth) into the
        live image for live keypoints without live depth."""
        i_live, i_kf = self._guided(node, T_map_live)
        z_kf = self._map_depth(node, np.arange(len(self.map.features[node].keypoints)))
        if z_kf is not None and self.params.verify.map_depth:
            m, f = self.map, self.map.features[node]
            kf_pts = backproject_pixels(m.K[node], np.asarray(f.keypoints, np.float64).reshape(-1, 2), z_kf)
            kf_pts[~(z_kf > 0)] = np.nan
            j_kf, j_live = guided_matches(kf_pts, f.descriptors, m.T_map_camera[node], self.feats.keypoints,
                                          self.feats.descriptors, self.K, T_map_live, self.params.refine)
            new = ~np.all(np.isfinite(self.points()[j_live]), axis=1) & ~np.isin(j_live, i_live)
            i_live, i_kf = np.concatenate([i_live, j_live[new]]), np.concatenate([i_kf, j_kf[new]])
        return self._observations(node, i_live, i_kf)
