"""Refresh a map from a new session (`litevloc map update MAP SRC -o NEW`).

The new session is localized against the map (by the caller: the runtime's localizer);
each localized frame is then compared with the nearest keyframes that look its way
(position within `match_radius_m`, viewing direction within `place_angle_deg`): the number
of a keyframe's matches the frame's pose explains (reprojection within `reprojection_px`)
is the match quality. A keyframe *covers* the frame's place when it is also within
`place_radius_m`. Then:

* **known place**: some nearby keyframe explains at least `changed_max_consistent` matches
  (the map already localizes this view, even between keyframes more than `place_radius_m`
  apart) -> nothing to add;
* **new place**: no keyframe covers the frame's place, none nearby explains enough
  matches, the frame's own localization against the map (the localizer reaches farther
  keyframes, at other angles, with the matcher) has fewer than `changed_max_consistent`
  inliers, and the map's keyframes did not see its view (`mapped_view`: less than
  `mapped_view_share` of its keypoints' ground-plane cells and heading bins, map building's
  coverage, among theirs) -> the frame is a keyframe candidate. A frame whose view the map
  saw from elsewhere but no longer matches is at a mapped place and, matching nothing, is
  skipped as a covered frame would be (`UpdateReport.mapped_view_unmatched`): months after
  mapping most unmatched frames are views the map has, and adding each as a new place grew
  the map every update. A frame the map localizes well from
  elsewhere is a known place (`UpdateReport.known_by_localization`): a new keyframe is
  added where the map fails to localize, not wherever the session left the mapped path;
* **changed place**: keyframes cover it but explain fewer than `changed_max_consistent`
  matches (moved furniture, new posters, other lighting) -> a keyframe candidate too;
* **retired node**: a keyframe visited at least `retire_min_visits` times whose best
  match quality stayed at or below `retire_max_consistent` no longer matches its place. A
  visit counts only when the frame itself matched well (another covering keyframe, or the
  localization, reached `changed_max_consistent`): a blurred frame retires nothing. The
  keyframes are matched nearest first and the first that explains `changed_max_consistent`
  matches ends the search, so a visit is counted only for a keyframe actually matched;
* a frame at a mapped place that matched well neither there nor in its localization is
  skipped as unreliable (counted). The localization's support is asked for (`observe`'s
  `localize`) only when neither the nearby keyframes nor an added one matched well: a posed
  session need not localize the frames the map already knows;
* candidates are kept only when at least `min_spacing_m` / `min_spacing_deg` from each
  other (and, for new places, that far from every keyframe), so a session adds keyframes
  where the map lacks them, not at every frame. The defaults are the place criterion
  (`place_radius_m`, `place_angle_deg`): a kept candidate covers its place as a keyframe
  does, so a closer one would be a second keyframe for the same place;
* a frame that no old keyframe explains is next compared with the keyframes this update
  has already added (nearest first, the same reach and test): if one explains it, it is
  known by the added keyframe (`UpdateReport.known_by_added`), not a new candidate. The
  session's frames thus extend the map as a keyframe would serve them: along a new path a
  keyframe is added where the last added one stops matching, not at every `min_spacing_m`;
* a changed-place candidate *replaces* the stale keyframes of its place, or is dropped, as the
  session's other frames there measure it (`pipelines.topomap.replace`, `UpdateParams.replace`):
  a place is refreshed, not stacked with a keyframe per visit.

`MapUpdate.finish` writes nothing: it returns the new map (old nodes minus retired, plus
added; covisibility verified by PnP for every new node, matched as the map build matches
(`CovisibilityParams.matching`: guided by the poses by default); connectivity repaired around
retired nodes and extended to new ones through free space; the occupancy grid extended
with the new observations — obstacles are added, never cleared) and a report. Pure: arrays
and an injected matcher in, a map out.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from litevloc.base.geometry import backproject_pixels, invert, rotation_angle
from litevloc.base.params.map_maintenance import MergeParams, UpdateParams
from litevloc.base.params.mapping import ConnectivityParams, CovisibilityParams, KeyframeParams, OccupancyParams
from litevloc.pipelines.guided_matching import match_by_projection
from litevloc.pipelines.topomap.graphs import MatchFn, lift_keypoints, pair_inliers
from litevloc.pipelines.topomap.keyframes import keypoint_view_keys
from litevloc.pipelines.topomap.occupancy import build_occupancy, segment_is_free
from litevloc.pipelines.topomap.replace import Decision, Keyframes, plan_replacements
from litevloc.pipelines.topomap.types import FeatureSet, NodeFeatures, OccupancyGrid, TopoMap


@dataclass(frozen=True, eq=False)
class Observation:
    """One localized frame of the new session (everything a keyframe needs)."""

    t_ns: int
    index: int
    T_map_camera: NDArray[np.float64]  # 4x4, from localization against the map
    K: NDArray[np.float64]  # 3x3
    image_size: tuple[int, int]  # (width, height)
    features: NodeFeatures
    keypoint_depth: NDArray[np.float32]  # (N,) metres at each keypoint, NaN = none
    vpr: NDArray[np.float32]  # (D,)
    jpeg: bytes
    points_map: NDArray[np.float32]  # (P, 3) subsampled depth points in the map frame (for the grid)
    localization_inliers: int = 0  # PnP inliers of the localization that gave the pose (0 = unknown)


@dataclass
class UpdateReport:
    frames: int = 0
    known: int = 0
    new_place: int = 0
    changed_place: int = 0
    unreliable: int = 0  # at a mapped place, but neither the place's keyframes nor the localization matched well
    mapped_view_unmatched: int = 0  # of `unreliable`: no keyframe covers it, but the map saw its view
    known_by_added: int = 0  # explained by a keyframe this update added (counted in `known` too)
    known_by_localization: int = 0  # no keyframe covers it, but the map localizes it well (in `known` too)
    added: list[int] = field(default_factory=list)  # new node ids in the updated map
    retired: list[int] = field(default_factory=list)  # node ids of the old map
    replaced: list[int] = field(default_factory=list)  # of `retired`: stale keyframes a candidate replaced
    replace_outcomes: dict[str, int] = field(default_factory=dict)  # changed-place candidates by `Outcome`
    visits: dict[int, int] = field(default_factory=dict)
    best_consistent: dict[int, int] = field(default_factory=dict)


def consistent_matches(
    T_map_camera: NDArray[np.float64], feats: FeatureSet, keypoint_depth: NDArray[np.float32],
    K: NDArray[np.float64], node_feats: FeatureSet, T_map_node: NDArray[np.float64], K_node: NDArray[np.float64],
    match: MatchFn, reprojection_px: float,
) -> int:
    """Matches between a posed frame and a keyframe that the pose explains (the frame's
    depth-lifted keypoints reproject within `reprojection_px` of their keyframe match)."""
    i_live, i_node = match(feats, node_feats)
    if len(i_live) == 0:
        return 0
    z = keypoint_depth[i_live]
    ok = np.isfinite(z)
    if not ok.any():
        return 0
    pts = backproject_pixels(K, np.asarray(feats.keypoints, np.float64)[i_live[ok]], z[ok].astype(np.float64))
    T = invert(T_map_node) @ T_map_camera
    pc = pts @ T[:3, :3].T + T[:3, 3]
    front = pc[:, 2] > 1e-3
    proj = (pc[front, :2] / pc[front, 2:3]) * [K_node[0, 0], K_node[1, 1]] + [K_node[0, 2], K_node[1, 2]]
    ref = np.asarray(node_feats.keypoints, np.float64)[i_node[ok]][front]
    return int(np.count_nonzero(np.linalg.norm(proj - ref, axis=1) <= reprojection_px))


def guided_consistent_matches(
    T_map_camera: NDArray[np.float64], feats: FeatureSet, keypoint_depth: NDArray[np.float32],
    K: NDArray[np.float64], node_feats: FeatureSet, T_map_node: NDArray[np.float64], K_node: NDArray[np.float64],
    reprojection_px: float, min_similarity: float,
) -> int:
    """As `consistent_matches`, with the matches found by the pose itself (no model run,
    ~1-5 ms): each depth-lifted keypoint of the frame is projected into the keyframe and
    paired with the most similar keyframe keypoint within `reprojection_px` (mutual best,
    descriptor similarity >= `min_similarity`, `guided_matching.match_by_projection`) that is
    also the mutual nearest neighbour over all keypoints of both images: the pose filters the
    matches, it does not choose them (so it cannot confirm itself on a repetitive texture)."""
    pts = lift_keypoints(K, feats.keypoints, keypoint_depth)
    i_live, _ = match_by_projection(pts, feats.descriptors, T_map_camera, node_feats.keypoints,
                                    node_feats.descriptors, K_node, T_map_node, reprojection_px, min_similarity,
                                    global_mutual=True)
    return len(i_live)


def _stack(arrays: list[NDArray[np.floating]], shape: tuple[int, ...]) -> NDArray[np.float64]:
    """np.stack that also works for no arrays: (0, *shape)."""
    return np.stack(arrays).astype(np.float64) if arrays else np.zeros((0, *shape))


def keyframe_view_keys(topomap: TopoMap, node: int, ref_height: float, params: KeyframeParams) -> NDArray[np.int64]:
    """`keyframes.keypoint_view_keys` of a keyframe (its keypoints with the map's depth);
    `ref_height`: the camera height (metres along up) the height band is measured from."""
    return keypoint_view_keys(topomap.K[node], topomap.features[node].keypoints, topomap.keypoint_depth(node),
                              topomap.T_map_camera[node], topomap.grid.up, ref_height, params)


def map_view_keys(topomap: TopoMap, params: KeyframeParams) -> tuple[NDArray[np.int64], float]:
    """(the unique view keys of all the map's keyframes, their median camera height along up (m)):
    what the map saw, and the height reference to compare other views with."""
    ref = float(np.median(topomap.T_map_camera[:, :3, 3] @ topomap.grid.up))
    views = [keyframe_view_keys(topomap, i, ref, params) for i in range(topomap.n_nodes)]
    return np.unique(np.concatenate([np.zeros(0, np.int64), *views])), ref


class MapUpdate:
    """Feed localized frames with `observe`, then `finish` into the updated map."""

    def __init__(self, topomap: TopoMap, match: MatchFn, params: UpdateParams | None = None,
                 keyframes: KeyframeParams | None = None) -> None:
        self.map = topomap
        self.match = match
        self.params = params or UpdateParams()
        self._view_params = keyframes or KeyframeParams()  # the cells and heading bins of a view
        self._seen: tuple[NDArray[np.int64], float] | None = None  # `map_view_keys`, once a frame asks
        self._tree = cKDTree(topomap.positions)
        self._cos_place = float(np.cos(np.radians(self.params.place_angle_deg)))
        self.candidates: list[Observation] = []
        self._changed: list[bool] = []  # per candidate: a changed place (else a new one)
        self._probes: dict[int, Observation] = {}  # well-matched frames by index: the held-out pool
        self.cameras: list[NDArray[np.float64]] = []
        self.points: list[NDArray[np.float32]] = []
        self.report = UpdateReport()

    def nearby_nodes(self, T_map_camera: NDArray[np.float64], radius_m: float) -> list[int]:
        """Keyframes within `radius_m` of the pose looking within `place_angle_deg` of its
        direction, nearest first."""
        p, z = T_map_camera[:3, 3], T_map_camera[:3, 2]
        near = self._tree.query_ball_point(p, r=radius_m)
        ok = [int(i) for i in near if float(self.map.T_map_camera[i, :3, 2] @ z) >= self._cos_place]
        return sorted(ok, key=lambda i: float(np.linalg.norm(self.map.positions[i] - p)))

    def covering_nodes(self, T_map_camera: NDArray[np.float64]) -> list[int]:
        """Keyframes covering the pose's place (within `place_radius_m`), nearest first."""
        return self.nearby_nodes(T_map_camera, self.params.place_radius_m)

    def _spaced(self, T: NDArray[np.float64], others: list[NDArray[np.float64]]) -> bool:
        p = self.params
        for To in others:
            if (np.linalg.norm(To[:3, 3] - T[:3, 3]) < p.min_spacing_m
                    and np.degrees(rotation_angle(To[:3, :3].T @ T[:3, :3])) < p.min_spacing_deg):
                return False
        return True

    def observe(self, obs: Observation, localize: Callable[[], int] | None = None) -> str:
        """Classify one localized frame: 'known', 'new place', 'changed place' or 'unreliable'.

        `localize`, if given, returns the PnP inliers of the frame's own localization against
        the map (0 = not localized); it is called only when neither the nearby keyframes nor
        a keyframe this update added explain `changed_max_consistent` matches (known from
        elsewhere, new place, changed place or unreliable frame?), and its count then stands
        beside `obs.localization_inliers`."""
        r = self.report
        r.frames += 1
        self.cameras.append(obs.T_map_camera[:3, 3].copy())
        near = self.nearby_nodes(obs.T_map_camera, self.params.match_radius_m)[: self.params.nodes_checked]
        radius = self.params.place_radius_m
        cover = [n for n in near if float(np.linalg.norm(self.map.positions[n] - obs.T_map_camera[:3, 3])) <= radius]
        thr = self.params.changed_max_consistent
        # Nearest first (the covering keyframes are a prefix of `near`); the first keyframe that
        # explains `thr` matches decides the frame (known place, or changed place when it lies
        # beyond every covering one), so the rest are not matched.
        quality: dict[int, int] = {}
        for node in near:
            quality[node] = self._consistent(obs, self.map.features[node], self.map.T_map_camera[node],
                                             self.map.K[node])
            if quality[node] >= thr:
                break
        best = max(quality.values(), default=0)
        best_cover = max((quality[n] for n in cover if n in quality), default=0)
        explained = (best_cover if cover else best) >= thr
        by_added = not explained and self._explained_by_added(obs)
        support = obs.localization_inliers
        if best < thr and not by_added and localize is not None:
            support = max(support, int(localize()))
        matchable = max(best, support) >= thr or by_added
        if matchable:  # visits (for retirement) only by keyframes matched at the frame's own place
            self._probes[obs.index] = obs
            for node in cover:
                if node in quality:
                    r.visits[node] = r.visits.get(node, 0) + 1
                    r.best_consistent[node] = max(r.best_consistent.get(node, 0), quality[node])
        if explained:
            r.known += 1  # a covering keyframe still matches, or (no keyframe at the place) a nearby one does
            return "known"
        if by_added:
            r.known += 1
            r.known_by_added += 1
            return "known"
        if not cover and support >= thr:
            r.known += 1
            r.known_by_localization += 1
            return "known"
        if not cover and self.params.mapped_view and self.seen_share(obs) >= self.params.mapped_view_share:
            r.unreliable += 1  # a mapped view that nothing here matches, as a covered frame that matched nothing
            r.mapped_view_unmatched += 1
            return "unreliable"
        if not cover:
            status = "new place"
            r.new_place += 1
            near_nodes = [self.map.T_map_camera[i] for i in
                          self._tree.query_ball_point(obs.T_map_camera[:3, 3], r=self.params.min_spacing_m)]
            keep = self._spaced(obs.T_map_camera, near_nodes + [c.T_map_camera for c in self.candidates])
        elif matchable:
            status = "changed place"
            r.changed_place += 1
            keep = self._spaced(obs.T_map_camera, [c.T_map_camera for c in self.candidates])
        else:
            r.unreliable += 1
            return "unreliable"
        self.points.append(obs.points_map)
        if keep:
            self.candidates.append(obs)
            self._changed.append(status == "changed place")
        return status

    def seen_share(self, obs: Observation) -> float:
        """Share of the frame's view (`keyframes.keypoint_view_keys` of its keypoints with depth) that
        the map's keyframes saw (theirs, the same way); 0 for a frame without keypoint depth."""
        if self._seen is None:
            self._seen = map_view_keys(self.map, self._view_params)
        seen, ref = self._seen
        v = keypoint_view_keys(obs.K, obs.features.keypoints, obs.keypoint_depth, obs.T_map_camera, self.map.grid.up,
                               ref, self._view_params)
        return float(np.isin(v, seen).mean()) if len(v) else 0.0

    def _consistent(self, obs: Observation, node_feats: FeatureSet, T_map_node: NDArray[np.float64],
                    K_node: NDArray[np.float64]) -> int:
        """Matches between the frame and a keyframe that the frame's pose explains."""
        p = self.params
        if p.matching == "guided":
            return guided_consistent_matches(obs.T_map_camera, obs.features, obs.keypoint_depth, obs.K, node_feats,
                                             T_map_node, K_node, p.reprojection_px, p.guided_min_similarity)
        return consistent_matches(obs.T_map_camera, obs.features, obs.keypoint_depth, obs.K, node_feats, T_map_node,
                                  K_node, self.match, p.reprojection_px)

    def _explained_by_added(self, obs: Observation) -> bool:
        """Whether a keyframe added by this update (within `match_radius_m`, looking within
        `place_angle_deg`; nearest `nodes_checked` first) explains `changed_max_consistent`
        matches of the frame."""
        if not self.candidates:
            return False
        p = self.params
        pos = np.stack([c.T_map_camera[:3, 3] for c in self.candidates])
        z = np.stack([c.T_map_camera[:3, 2] for c in self.candidates])
        d = np.linalg.norm(pos - obs.T_map_camera[:3, 3], axis=1)
        ok = np.nonzero((d <= p.match_radius_m) & (z @ obs.T_map_camera[:3, 2] >= self._cos_place))[0]
        for k in ok[np.argsort(d[ok], kind="stable")][: p.nodes_checked]:
            c = self.candidates[int(k)]
            if self._consistent(obs, c.features, c.T_map_camera, c.K) >= p.changed_max_consistent:
                return True
        return False

    def retired_nodes(self) -> list[int]:
        p, r = self.params, self.report
        return sorted(n for n, v in r.visits.items()
                      if v >= p.retire_min_visits and r.best_consistent.get(n, 0) <= p.retire_max_consistent)

    def replacements(self, retired: set[int], new_places: bool = False) -> list[Decision]:
        """The decisions on the changed-place candidates (`new_places`: on the new-place ones;
        `pipelines.topomap.replace`), given the keyframes the visit rule retires."""
        changed = [c for c, ch in zip(self.candidates, self._changed, strict=True) if ch != new_places]
        probes = [(i, o.T_map_camera) for i, o in self._probes.items()]

        def score(i: int, feats: FeatureSet, T: NDArray[np.float64], K: NDArray[np.float64]) -> int:
            return self._consistent(self._probes[i], feats, T, K)

        m = self.map
        return plan_replacements(Keyframes(m.T_map_camera, m.K, m.features),
                                 [(c.index, c.T_map_camera, c.features, c.K) for c in changed], probes, score,
                                 self.params, retired, new_places)

    def _replace(self, retired: set[int]) -> list[Observation]:
        """The candidates kept; stale keyframes they replace added to `retired`."""
        if not self.params.replace.enabled:
            return self.candidates
        decisions = iter(self.replacements(retired))
        fresh = iter(self.replacements(retired, new_places=True) if self.params.replace.new_places else [])
        kept: list[Observation] = []
        outcomes: dict[str, int] = {}
        for c, changed in zip(self.candidates, self._changed, strict=True):
            d = next(decisions) if changed else next(fresh, None)
            if d is None:
                kept.append(c)
                continue
            key = d.outcome.value if changed else f"new_place_{d.outcome.value}"
            outcomes[key] = outcomes.get(key, 0) + 1
            retired.update(d.replaced)
            self.report.replaced.extend(d.replaced)
            if d.kept:
                kept.append(c)
        self.report.replace_outcomes = outcomes
        self.report.replaced = sorted(set(self.report.replaced))
        return kept

    def finish(
        self, covisibility: CovisibilityParams, connectivity: ConnectivityParams, occupancy: OccupancyParams,
        on_pair: Callable[[], None] | None = None,
    ) -> tuple[TopoMap, UpdateReport]:
        """The updated map (see the module docstring) and what changed."""
        m, r = self.map, self.report
        retired = set(self.retired_nodes())
        cands = self._replace(retired)
        kept = [i for i in range(m.n_nodes) if i not in retired]
        new_id = {old: k for k, old in enumerate(kept)}
        n_kept = len(kept)
        T = np.concatenate([m.T_map_camera[kept], _stack([c.T_map_camera for c in cands], (4, 4))])
        K = np.concatenate([m.K[kept], _stack([c.K for c in cands], (3, 3))])
        feats: list[NodeFeatures] = [*(m.stored_features(i) for i in kept), *(c.features for c in cands)]
        grid = self._grid(occupancy)
        tree = cKDTree(T[:, :3, 3])
        covis = _covisibility(m, new_id, cands, T, K, feats, tree, self.match, covisibility, on_pair)
        conn = _connectivity(m, new_id, retired, n_kept, T[:, :3, 3], grid, tree, connectivity)
        ce = sorted(covis)
        ne = sorted(conn)
        meta = dict(m.meta)
        updated = TopoMap(
            T_map_camera=T, K=K,
            image_size=np.concatenate([m.image_size[kept], np.asarray([c.image_size for c in cands],
                                                                     np.int32).reshape(-1, 2)]),
            t_ns=np.concatenate([m.t_ns[kept], np.asarray([c.t_ns for c in cands], np.int64)]),
            frame_index=np.concatenate([m.frame_index[kept], np.asarray([c.index for c in cands], np.int64)]),
            vpr=np.concatenate([m.vpr[kept], _stack([c.vpr for c in cands], (m.vpr.shape[1],)).astype(np.float32)]),
            features=feats, images_jpeg=[*(m.images_jpeg[i] for i in kept), *(c.jpeg for c in cands)],
            covis_edges=np.asarray(ce, np.int64).reshape(-1, 2),
            covis_inliers=np.asarray([covis[e][0] for e in ce], np.int32),
            covis_weight=np.asarray([covis[e][1] for e in ce], np.float32),
            conn_edges=np.asarray(ne, np.int64).reshape(-1, 2), conn_metres=np.asarray([conn[e] for e in ne],
                                                                                      np.float32),
            grid=grid, extractor=m.extractor, vpr_model=m.vpr_model, meta=meta,
        )
        r.added = list(range(n_kept, n_kept + len(cands)))
        r.retired = sorted(retired)
        return updated, r

    def _grid(self, occupancy: OccupancyParams) -> OccupancyGrid:
        """The old grid, extended with the new session's observations (occupied wins)."""
        old = self.map.grid
        if not self.points:
            return old
        pts = np.concatenate(self.points).astype(np.float64)
        cams = np.asarray(self.cameras, np.float64).reshape(-1, 3)
        fresh = build_occupancy(pts, np.concatenate([cams, self.map.positions]), old.up,
                                OccupancyParams(old.resolution, occupancy.obstacle_band_m, occupancy.min_points,
                                                occupancy.margin_m))
        from litevloc.pipelines.topomap.merge import fuse_grids

        return fuse_grids(old, fresh, MergeParams())  # one ground plane (`old.up`): the up check cannot fire


def _covisibility(
    m: TopoMap, new_id: dict[int, int], cands: list[Observation], T: NDArray[np.float64], K: NDArray[np.float64],
    feats: list[NodeFeatures], tree: cKDTree, match: MatchFn, covisibility: CovisibilityParams,
    on_pair: Callable[[], None] | None,
) -> dict[tuple[int, int], tuple[int, float]]:
    """Covisibility edges (i, j) -> (inliers, weight) of the updated map: the old edges between
    kept nodes (`new_id`: old id -> new id) plus, for every new node (ids after the kept ones),
    the PnP-verified edges to nodes within `max_distance_m` and `max_angle_deg`. `T`, `K`,
    `feats` and `tree` (over T's positions) are the updated map's nodes; `on_pair` is called
    after every pair verified."""
    covis: dict[tuple[int, int], tuple[int, float]] = {}
    for (i, j), n, w in zip(m.covis_edges.tolist(), m.covis_inliers.tolist(), m.covis_weight.tolist(), strict=True):
        if i in new_id and j in new_id:
            covis[(new_id[i], new_id[j])] = (int(n), float(w))
    pos, z = T[:, :3, 3], T[:, :3, 2]
    cos_max = np.cos(np.radians(covisibility.max_angle_deg))
    n_kept = len(new_id)
    for k, c in enumerate(cands):
        a = n_kept + k
        for b in tree.query_ball_point(pos[a], r=covisibility.max_distance_m):
            if b == a or (b > a) or float(z[a] @ z[b]) < cos_max:
                continue  # each new pair once (b < a covers kept nodes and earlier new ones)
            n_in = pair_inliers(c.features, c.keypoint_depth, c.K, T[a], feats[b], K[b], T[b], match, covisibility)
            if on_pair is not None:
                on_pair()
            if n_in >= covisibility.min_inliers:
                covis[(b, a)] = (n_in, min(n_in / covisibility.weight_saturation, 1.0))
    return covis


def _connectivity(
    m: TopoMap, new_id: dict[int, int], retired: set[int], n_kept: int, pos: NDArray[np.float64],
    grid: OccupancyGrid, tree: cKDTree, connectivity: ConnectivityParams,
) -> dict[tuple[int, int], float]:
    """Connectivity edges (i, j) -> metres of the updated map: the old edges between kept nodes,
    repaired around `retired` nodes and extended from every new node (ids from `n_kept`) to its
    `max_line_of_sight_neighbours` nearest within `max_line_of_sight_m`, each link only through
    free space of `grid`. `pos` (N, 3) are the updated nodes' positions (map frame, m), `tree`
    over them."""
    conn: dict[tuple[int, int], float] = {}
    nb_old: dict[int, list[int]] = {}
    for (i, j), d in zip(m.conn_edges.tolist(), m.conn_metres.tolist(), strict=True):
        if i in new_id and j in new_id:
            conn[(new_id[i], new_id[j])] = float(d)
        nb_old.setdefault(i, []).append(j)
        nb_old.setdefault(j, []).append(i)
    xy = grid.to_plane(pos)

    def link(a: int, b: int) -> None:
        e = (min(a, b), max(a, b))
        d = float(np.linalg.norm(xy[a] - xy[b]))
        if a != b and segment_is_free(grid, xy[a], xy[b]):
            conn[e] = min(conn.get(e, np.inf), d)

    for gone in retired:  # neighbours of a retired node stay connected where the way is free
        around = [new_id[n] for n in nb_old.get(gone, []) if n in new_id]
        for x in range(len(around)):
            for y in range(x + 1, len(around)):
                link(around[x], around[y])
    for a in range(n_kept, len(pos)):
        near = sorted(tree.query_ball_point(pos[a], r=max(connectivity.max_line_of_sight_m, 1e-6)),
                      key=lambda b: float(np.linalg.norm(xy[a] - xy[b])))
        for b in [b for b in near if b != a][: connectivity.max_line_of_sight_neighbours]:
            link(a, b)
    return conn
