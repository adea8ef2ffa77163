"""Image-goal navigation on the connectivity graph (the planner computer's side).

* `localize_goal`: the goal image is placed on a map node by VPR top-k retrieval **plus
  geometric verification** (the published research code takes VPR top-1 unchecked): the
  first `top_k` keyframes by place descriptor (with `rerank_depth` > 0, the first that many
  re-ordered by their count of mutual nearest neighbours with the goal's local descriptors,
  `rerank`) are the candidates; the goal's features are matched to each candidate keyframe's
  cached features and an essential matrix is fitted with RANSAC; the keyframes near the
  strongest candidates (in place and viewing direction) are verified too, since the one that
  saw the goal's view best often ranks far down in retrieval; the candidate with most inliers wins if it has
  at least `min_inliers`. A goal that matches no place is reported as such. Where the map
  stores keypoint depth, `goal_pose` then gives the goal camera's metric pose (PnP against
  the keyframe's depth-lifted keypoints), so the robot can drive to where the image was
  taken rather than to the keyframe that saw it. With depth, every candidate gets such a
  pose, and a goal that verifies as well (within `ambiguity_ratio`) at another place is
  refused as ambiguous: the same poster hangs in two rooms, and guessing sends the robot
  to the wrong one. Candidates whose goal poses agree, or whose keyframes are covisible in
  the map, are one place. Where the PnP supports leave a goal ambiguous, the support points off
  the densest horizontal band (floor or ceiling tiles, which repeat and fit a tile off) are counted
  alone, and a place that holds enough of them and `ambiguity_ratio` times any other's is chosen
  after all (`ambiguity_band_m`). A candidate whose PnP inliers all lie on one plane (`plane_rms`
  below `planar_rms_m`) matched a single flat patch -- a poster, a sign, one wall -- which
  can hang at several places, so it needs `planar_factor` x `min_inliers` to verify a place;
  otherwise the goal is refused and the reason says so. A goal that verifies at a node of a
  map with depth but gives no metric pose there is refused too (`require_pose`): it has no
  place to check against rival places or the occupancy grid, and the node alone can be metres
  from where the image was taken (a keyframe that saw the goal's scene from across a room).
  A candidate's pose is dropped where it cannot be where the image was taken (`pose_doubt`):
  inside an obstacle of the grid, or at the keyframe's own view while explaining little of it.
  A candidate whose PnP support holds fewer than `pose_min_distinct` points off the floor and
  ceiling band matched tiles alone and verifies no place. Where the best verified candidate gets
  no pose from its own keyframe's depth points (too few PnP inliers, too far), it is posed from
  its and its covisible candidates' depth points together (`pose_pool_covisible`); failing that,
  the strongest posed verified candidate whose keyframe lies within `pose_fallback_m` of its
  keyframe stands for it.
* `shortest_path`: Dijkstra on the connectivity graph (edge weights in metres) with
  `scipy.sparse.csgraph.dijkstra` on the map's CSR matrix (built once per map); ~1 ms at
  10,000 nodes where the former pure-Python heap took tens (`bench/scale.py`).
  The tracker plans on `against_view_graph`: an edge driven against both of its keyframes'
  viewing directions costs `tracker.against_view_cost` times its length.
* `SubgoalTracker`: follows the path node by node, advancing when the robot is within
  `reach_m` of the current subgoal, replanning from the nearest node when the robot strays
  farther than `stray_m` from the path segment it is on (last reached node or start ->
  current subgoal), and reporting idle/planned/reached/failed. The nearest node comes
  from a KD-tree (`topomap.node_index.NodeIndex`) over the tracker's node positions. Where
  the straight line to the subgoal node crosses a wall on the occupancy grid, `NavStatus.via`
  is the next turn of the grid path there (`approach.plan_approach`, `leg_detour_m`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import cv2
import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray
from scipy.sparse.csgraph import dijkstra

from litevloc.base.errors import LiteVLocError
from litevloc.base.geometry import backproject_pixels, invert, project, transform_points
from litevloc.base.params.navigation import GoalParams, TrackerParams
from litevloc.pipelines.guided_matching import mutual_nn_count
from litevloc.pipelines.navigation.approach import plan_approach
from litevloc.pipelines.pnp import solve_pnp
from litevloc.pipelines.topomap.node_index import ZERO_EDGE_M, NodeIndex
from litevloc.pipelines.topomap.types import FeatureSet, TopoMap

MatchFn = Callable[[FeatureSet, FeatureSet], tuple[NDArray[np.int64], NDArray[np.int64]]]


class NavigationError(LiteVLocError, ValueError):
    """No path, bad node ids, or an unusable goal."""


@dataclass(frozen=True)
class GoalResult:
    """Where a goal image is: its map node (None: not placed, see `reason`) and, where the
    map has keypoint depth, the goal camera's metric pose in the map (4x4 `T_map_camera`)."""

    node: int | None
    inliers: int
    reason: str
    candidates: tuple[tuple[int, float, int], ...] = ()  # (node, similarity, inliers)
    T_map_goal: NDArray[np.float64] | None = None  # None: no metric pose (no keypoint depth, or PnP failed)
    pose_inliers: int = 0


@dataclass(frozen=True)
class GoalPose:
    """PnP of a goal image against one keyframe's depth-lifted keypoints.

    T_node_goal: 4x4 goal camera pose in the keyframe camera's frame (metres); None when
    there is no depth, too few inliers or the pose is implausibly far.
    inliers: PnP inliers; where PnP did not run (too few matches with depth), those matches.
    plane_rms_m: RMS distance (m) of the inliers' 3D points from their best-fitting plane;
    NaN without a pose. Near zero: the whole support is one flat patch (a poster, a sign,
    one wall), which can hang at several places.
    support_points: (M, 3) the PnP inliers' 3D points in the keyframe camera frame (metres);
    empty without a pose.
    """

    T_node_goal: NDArray[np.float64] | None
    inliers: int
    plane_rms_m: float = float("nan")
    support_points: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 3)))


def plane_rms(points: NDArray[np.float64]) -> float:
    """RMS distance (m) of (N, 3) points from their least-squares plane (the smallest
    singular value of the centred points over sqrt(N)); NaN for fewer than 3 points."""
    if len(points) < 3:
        return float("nan")
    c = points - points.mean(axis=0)
    return float(np.linalg.svd(c, compute_uv=False)[-1] / np.sqrt(len(points)))


def goal_pose(goal_feats: FeatureSet, K_goal: NDArray[np.float64], i_goal: NDArray[np.int64],
              points_node: NDArray[np.float64], params: GoalParams) -> GoalPose:
    """The goal camera's pose in a keyframe camera's frame by PnP + RANSAC of the goal keypoints
    `i_goal` (M,) against the keyframe's matched keypoints lifted with their mapping depth
    (`points_node` (M, 3) metres, `lift_matches`); no pose with too few inliers
    (< `pose_min_inliers`) or farther than `pose_max_m` from the keyframe."""
    gp = _pnp_pose(goal_feats, K_goal, i_goal, points_node, params)
    if gp.T_node_goal is not None and np.linalg.norm(gp.T_node_goal[:3, 3]) > params.pose_max_m:
        return GoalPose(None, gp.inliers)
    return gp


def lift_matches(node_feats: FeatureSet, node_depth: NDArray[np.float32], K_node: NDArray[np.float64],
                 matches: tuple[NDArray[np.int64], NDArray[np.int64]]) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """The matches (goal indices, node indices) whose keyframe keypoint has mapping depth
    (`node_depth` (N_node,) metres, NaN = none): their goal keypoint indices (M,) and the
    keyframe keypoints lifted to 3D, (M, 3) metres in the keyframe camera frame."""
    i_goal, i_node = matches
    z = np.asarray(node_depth, np.float64)[i_node]
    ok = np.isfinite(z) & (z > 0)
    pts = backproject_pixels(K_node, np.asarray(node_feats.keypoints, np.float64)[i_node[ok]], z[ok])
    return np.asarray(i_goal, np.int64)[ok], pts.reshape(-1, 3)


def _pnp_pose(goal_feats: FeatureSet, K_goal: NDArray[np.float64], i_goal: NDArray[np.int64],
              points: NDArray[np.float64], params: GoalParams) -> GoalPose:
    """PnP + RANSAC of the goal keypoints `i_goal` (M,) against their 3D points (M, 3, metres, in
    one frame F): the goal camera's `GoalPose` in F; no pose below `pose_min_inliers` (`pose_max_m`
    is the caller's: from one keyframe, or from the nearest of a pool)."""
    if len(i_goal) < params.pose_min_inliers:
        return GoalPose(None, len(i_goal))
    res = solve_pnp(points, np.asarray(goal_feats.keypoints, np.float64)[i_goal], K_goal, params.pose_pnp())
    n = res.n_ransac_inliers  # the support: RANSAC's consensus, not the refined pose's re-scored inliers
    if res.T_target_source is None or n < params.pose_min_inliers:
        return GoalPose(None, n)
    idx = res.ransac_inliers
    T_f_goal = invert(res.T_target_source)
    if not np.all(np.isfinite(T_f_goal)):
        return GoalPose(None, n)
    return GoalPose(T_f_goal, n, plane_rms(points[idx]), points[idx])


def horizontal_share(points_map: NDArray[np.float64], up: NDArray[np.float64], band_m: float = 0.04) -> float:
    """Largest share (0-1) of (N, 3) map points whose heights along `up` (unit 3-vector)
    lie within one band of `band_m` metres: the part of a support that rests on one
    horizontal surface (floor or ceiling tiles, which repeat everywhere). NaN for no points."""
    if len(points_map) == 0:
        return float("nan")
    h = np.sort(np.asarray(points_map, np.float64) @ np.asarray(up, np.float64))
    in_band = np.searchsorted(h, h + band_m, side="right") - np.arange(len(h))
    return float(in_band.max() / len(h))


def essential_inliers(
    f0: FeatureSet, K0: NDArray[np.float64], f1: FeatureSet, K1: NDArray[np.float64], match: MatchFn,
    params: GoalParams, matches: tuple[NDArray[np.int64], NDArray[np.int64]] | None = None,
) -> int:
    """Inliers of an essential matrix (RANSAC) between two images' matched features
    (`matches`: already computed, else `match(f0, f1)`)."""
    i0, i1 = match(f0, f1) if matches is None else matches
    if len(i0) < 8:
        return 0
    p0 = cv2.undistortPoints(np.asarray(f0.keypoints, np.float64)[i0].reshape(-1, 1, 2), K0, None).reshape(-1, 2)
    p1 = cv2.undistortPoints(np.asarray(f1.keypoints, np.float64)[i1].reshape(-1, 1, 2), K1, None).reshape(-1, 2)
    focal = 0.5 * (K0[0, 0] + K1[0, 0])
    cv2.setRNGSeed(params.seed)
    E, mask = cv2.findEssentialMat(p0, p1, np.eye(3), method=cv2.RANSAC, prob=0.999,
                                   threshold=params.ransac_px / focal)
    return 0 if E is None or mask is None else int(mask.sum())


@dataclass(frozen=True)
class _Candidate:
    node: int
    similarity: float
    inliers: int  # essential-matrix inliers
    T_map_goal: NDArray[np.float64] | None
    pose_inliers: int
    plane_rms_m: float = float("nan")
    support_points: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 3)))  # GoalPose's, node frame
    pose_doubt: str = ""  # why its PnP pose was dropped (`pose_doubt`), "" if it was not
    tiles: tuple[int, int] | None = None  # (distinctive, all) PnP support where it rests on floor/ceiling tiles

    def planar(self, params: GoalParams) -> bool:
        """True when the candidate's PnP support is one flat patch (see `GoalParams.planar_rms_m`)."""
        return params.planar_rms_m > 0 and bool(self.plane_rms_m < params.planar_rms_m)

    def needed(self, params: GoalParams) -> float:
        """Essential-matrix inliers this candidate needs to verify a place (none suffice for a
        match on floor or ceiling tiles alone)."""
        if self.tiles is not None:
            return float("inf")
        return params.min_inliers * (params.planar_factor if self.planar(params) else 1.0)


def pose_doubt(topomap: TopoMap, node: int, T_map_goal: NDArray[np.float64], K_goal: NDArray[np.float64],
               pose_inliers: int, params: GoalParams) -> str:
    """Why a candidate's metric goal pose (4x4, map frame) cannot be where the goal image was
    taken, or "": (`pose_outside_obstacles`) its camera lies in an OCCUPIED cell of the map's
    grid, inside a wall; or (`pose_min_explained`) it lies within `agree_m` / `agree_deg` of the
    keyframe, so the image sees what the keyframe saw, yet the PnP explains less than that share
    of the keyframe's depth keypoints that project into the goal image (taken as 2 cx x 2 cy
    pixels): a repeating texture (floor tiles, striped wallpaper) fitted to the keyframe's own
    view. Goal images that close to their keyframe match over a quarter of them."""
    p = T_map_goal[:3, 3]
    if params.pose_outside_obstacles and not segment_clear(topomap, p, p, 0.0):  # the camera's own cell
        return "its pose lies inside an obstacle of the map's occupancy grid"
    T_kf = topomap.T_map_camera[node]
    depth = topomap.keypoint_depth(node)
    if params.pose_min_explained <= 0 or depth is None \
            or np.linalg.norm(p - T_kf[:3, 3]) > params.agree_m \
            or float(T_map_goal[:3, 2] @ T_kf[:3, 2]) < np.cos(np.radians(params.agree_deg)):
        return ""
    ok = np.isfinite(depth)
    pts = backproject_pixels(topomap.K[node], np.asarray(topomap.features[node].keypoints, np.float64)[ok], depth[ok])
    pc = transform_points(invert(T_map_goal) @ T_kf, pts)
    uv = project(K_goal, pc[pc[:, 2] > 1e-3])
    seen = int(np.all((uv >= 0) & (uv < 2 * K_goal[:2, 2]), axis=1).sum())
    if seen and pose_inliers < params.pose_min_explained * seen:
        return (f"its pose lies at keyframe {node}'s own view yet explains {pose_inliers} of the {seen} keypoints "
                f"the keyframe sees there (< {params.pose_min_explained:g}: a repeating texture fitted to its view)")
    return ""


def _places(cands: list[_Candidate], agree_m: float, agree_deg: float,
            to_plane: Callable[[NDArray[np.float64]], NDArray[np.float64]],
            covisible: Callable[[int, int], bool] = lambda a, b: False) -> list[list[_Candidate]]:
    """Candidates with a metric goal pose grouped into places: greedy, strongest PnP first; a
    candidate joins the first place whose seed pose lies within agree_m along the floor (the
    map grid's `to_plane`: a goal is a spot to drive to, and PnP's height is its least certain
    part) and agree_deg (angle between the optical axes) of its own, or whose
    seed's keyframe is covisible with its own (the map verified that the two keyframes see the
    same scene: in a long corridor the goal poses of neighbouring keyframes can differ by a
    metre, and that is one place)."""
    places: list[list[_Candidate]] = []
    for c in sorted((c for c in cands if c.T_map_goal is not None), key=lambda c: -c.pose_inliers):
        assert c.T_map_goal is not None
        for place in places:
            seed = place[0].T_map_goal
            assert seed is not None
            if covisible(place[0].node, c.node) or _agree(seed, c.T_map_goal, agree_m, agree_deg, to_plane):
                place.append(c)
                break
        else:
            places.append([c])
    return places


def _agree(T_a: NDArray[np.float64], T_b: NDArray[np.float64], agree_m: float, agree_deg: float,
           to_plane: Callable[[NDArray[np.float64]], NDArray[np.float64]]) -> bool:
    """Whether two goal poses (4x4 T_map_goal) are one spot: within `agree_m` along the floor
    (`to_plane`) and `agree_deg` between their optical axes."""
    apart = float(np.linalg.norm(np.diff(to_plane(np.stack([T_a[:3, 3], T_b[:3, 3]])), axis=0)))
    return apart <= agree_m and float(T_a[:3, 2] @ T_b[:3, 2]) >= float(np.cos(np.radians(agree_deg)))


def _consensus(place: list[_Candidate], agree_m: float, agree_deg: float,
               to_plane: Callable[[NDArray[np.float64]], NDArray[np.float64]]) -> _Candidate:
    """The strongest place member (most PnP inliers) among those whose goal poses agree (`_agree`)
    with the pose the most PnP support agrees with: a member joined by covisibility can sit metres
    off, and so can the strongest one."""
    def agreeing(c: _Candidate) -> list[_Candidate]:
        assert c.T_map_goal is not None
        return [o for o in place
                if o.T_map_goal is not None and _agree(c.T_map_goal, o.T_map_goal, agree_m, agree_deg, to_plane)]

    centre = max(place, key=lambda c: (sum(o.pose_inliers for o in agreeing(c)), c.pose_inliers))
    return max(agreeing(centre), key=lambda c: c.pose_inliers)


def _neighbours(topomap: TopoMap, cands: list[_Candidate], params: GoalParams) -> list[int]:
    """Keyframes to verify next to the strongest candidates (see `GoalParams.expand_k`): up to
    `expand_k` per candidate, nearest first, not yet verified."""
    if params.expand_k == 0:
        return []
    tried = {c.node for c in cands}
    pos = np.asarray(topomap.positions, np.float64)
    axis = np.asarray(topomap.T_map_camera, np.float64)[:, :3, 2]
    cos_max = float(np.cos(np.radians(params.expand_deg)))
    out: list[int] = []
    strong = [c for c in sorted(cands, key=lambda c: -c.inliers) if c.inliers >= params.expand_min_inliers]
    for c in strong[: params.expand_from]:
        d = np.linalg.norm(pos - pos[c.node], axis=1)
        ok = (d <= params.expand_m) & (axis @ axis[c.node] >= cos_max)
        near = [int(k) for k in np.argsort(d, kind="stable") if ok[k] and int(k) not in tried and int(k) not in out]
        out += near[: params.expand_k]
    return out


def rerank(goal_feats: FeatureSet, topomap: TopoMap, ranked: NDArray[np.int64],
           params: GoalParams) -> NDArray[np.int64]:
    """The first `rerank_depth` nodes of `ranked` (VPR order, best first) re-ordered by their
    mutual-nearest-neighbour count with the goal's descriptors (VPR order breaking ties), then
    the rest; `ranked` unchanged with `rerank_depth` 0. The place descriptor ranks the keyframe
    that saw the goal's view far down where the view is plain or seen from a new height; the
    local descriptors, compared without a model, still find it."""
    head = ranked[: params.rerank_depth]
    if len(head) < 2:
        return ranked
    goal = np.asarray(goal_feats.descriptors)
    counts = [mutual_nn_count(goal, topomap.features[int(n)].descriptors, params.rerank_min_similarity)
              for n in head]
    return np.concatenate([head[np.argsort(-np.asarray(counts), kind="stable")], ranked[len(head):]])


def localize_goal(
    goal_feats: FeatureSet, goal_desc: NDArray[np.float32], K_goal: NDArray[np.float64], topomap: TopoMap,
    match: MatchFn, params: GoalParams = GoalParams(),
) -> GoalResult:
    """Map node (and, with keypoint depth, metric pose) of a goal image, or `node=None` with
    the reason: no candidate verifies (< `min_inliers`), or the goal is ambiguous (another
    place's PnP support exceeds 1/`ambiguity_ratio` of the chosen one's). One match per
    top-k candidate serves both the essential matrix and the PnP."""
    sims = topomap.vpr @ np.asarray(goal_desc, np.float32)
    order = rerank(goal_feats, topomap, np.argsort(-sims, kind="stable"), params)[: params.top_k]

    lifted: dict[int, tuple[int, NDArray[np.int64], NDArray[np.float64]]] = {}  # node: (E inliers, goal idx, map pts)

    def judge(node: int, n_e: int, gp: GoalPose) -> _Candidate:
        T_map_goal = None if gp.T_node_goal is None else topomap.T_map_camera[node] @ gp.T_node_goal
        if T_map_goal is not None and params.pose_min_distinct > 0:
            distinct = distinctive_support(transform_points(topomap.T_map_camera[node], gp.support_points),
                                           topomap.grid.up, params.ambiguity_band_m)
            if distinct < params.pose_min_distinct:  # tiles repeat in every room: they verify no place
                return _Candidate(node, float(sims[node]), n_e, None, gp.inliers, tiles=(distinct, gp.inliers))
        doubt = "" if T_map_goal is None else pose_doubt(topomap, node, T_map_goal, K_goal, gp.inliers, params)
        if doubt:
            return _Candidate(node, float(sims[node]), n_e, None, gp.inliers, pose_doubt=doubt)
        return _Candidate(node, float(sims[node]), n_e, T_map_goal, gp.inliers, gp.plane_rms_m, gp.support_points)

    def verify(node: int) -> _Candidate:
        feats, K_node = topomap.features[node], topomap.K[node]
        pairs = match(goal_feats, feats)
        n_e = essential_inliers(goal_feats, K_goal, feats, K_node, match, params, pairs)
        depth = topomap.keypoint_depth(node)
        if depth is None:
            return judge(node, n_e, GoalPose(None, 0))
        i_goal, pts = lift_matches(feats, depth, K_node, pairs)
        lifted[node] = (n_e, i_goal, transform_points(topomap.T_map_camera[node], pts))
        return judge(node, n_e, goal_pose(goal_feats, K_goal, i_goal, pts, params))

    def pooled(c: _Candidate) -> _Candidate:
        """`c` posed from its own and its covisible candidates' depth points together, where its
        own keyframe's gave no pose (too few PnP inliers, too far). Only ever a verified candidate,
        never a tiles-only one: its tile matches, a tile off, would lead the pool to the wrong room."""
        if c.T_map_goal is not None or c.pose_doubt or c.node not in lifted:
            return c
        others = sorted((n for n in topomap.covisibility_lists[c.node] if n in lifted), key=lambda n: -lifted[n][0])
        pool = [c.node, *others]
        if len(pool) < 2:
            return c
        i_goal, pts = _unique_goal_points([lifted[n][1:] for n in pool])
        T_node_map = invert(topomap.T_map_camera[c.node])
        gp = _pnp_pose(goal_feats, K_goal, i_goal, transform_points(T_node_map, pts), params)
        if gp.T_node_goal is None:
            return c
        at = (topomap.T_map_camera[c.node] @ gp.T_node_goal)[:3, 3]  # within reach of a keyframe of the pool
        reach = min(float(np.linalg.norm(topomap.positions[n] - at)) for n in pool)
        return judge(c.node, c.inliers, gp) if reach <= params.pose_max_m else c

    cands = [verify(int(n)) for n in order]
    cands += [verify(n) for n in _neighbours(topomap, cands, params)]
    verified = [c for c in cands if c.inliers >= c.needed(params)]
    if params.pose_pool_covisible and verified:  # the best verified candidate lacks a pose: pose it from its place
        first = max(verified, key=lambda c: (c.inliers, c.similarity))
        cands = [pooled(c) if c is first else c for c in cands]
        verified = [c for c in cands if c.inliers >= c.needed(params)]
    table = tuple((c.node, c.similarity, c.inliers) for c in cands)
    strongest = max(cands, key=lambda c: (c.inliers, c.similarity))
    if not verified:
        if strongest.inliers >= params.min_inliers and strongest.tiles is not None:
            return GoalResult(None, strongest.inliers,
                              f"goal image matches only floor or ceiling tiles at node {strongest.node}: "
                              f"{strongest.inliers} inliers, of its PnP support {strongest.tiles[0]} of "
                              f"{strongest.tiles[1]} points off the tiles < {params.pose_min_distinct} (tiles repeat "
                              "in every room; an image with more of the place in view would tell it)", table)
        if strongest.inliers >= params.min_inliers:  # only flat support reached the bar
            return GoalResult(None, strongest.inliers,
                              f"goal image matches only a flat patch (a poster, a sign, one wall) at node "
                              f"{strongest.node}: {strongest.inliers} inliers within "
                              f"{100 * strongest.plane_rms_m:.1f} cm of one plane < {strongest.needed(params):.0f} "
                              "needed for flat support", table)
        return GoalResult(None, strongest.inliers, f"goal image matches no map place (best {strongest.inliers} "
                          f"inliers < {params.min_inliers})", table)
    best = max(verified, key=lambda c: (c.inliers, c.similarity))
    if best.T_map_goal is None and not best.pose_doubt and params.pose_fallback_m > 0:
        best = _posed_neighbour(topomap, verified, best, params.pose_fallback_m)
    if best.T_map_goal is None and params.require_pose and (best.pose_doubt
                                                             or topomap.keypoint_depth(best.node) is not None):
        why = (f": {best.pose_doubt}" if best.pose_doubt else
               f" (PnP: {best.pose_inliers} inliers, need {params.pose_min_inliers} and a pose within "
               f"{params.pose_max_m:g} m of the keyframe): where it was taken, and whether another place fits as "
               "well, cannot be checked")
        return GoalResult(None, best.inliers, f"goal image verifies at node {best.node} ({best.inliers} inliers) but "
                          f"gives no metric pose there{why}", table, None, best.pose_inliers)
    if best.T_map_goal is not None and params.ambiguity_ratio > 0:
        best, refusal = _unambiguous(topomap, cands, verified, best, params, table)
        if refusal is not None:
            return refusal
    return GoalResult(best.node, best.inliers, "ok", table, best.T_map_goal, best.pose_inliers)


def _posed_neighbour(topomap: TopoMap, verified: list[_Candidate], best: _Candidate, radius_m: float) -> _Candidate:
    """The verified candidate with a metric pose and most essential-matrix inliers whose keyframe lies
    within `radius_m` of `best`'s (the same place seen from nearby), else `best`."""
    pos = np.asarray(topomap.positions, np.float64)
    near = [c for c in verified if c.T_map_goal is not None
            and float(np.linalg.norm(pos[c.node] - pos[best.node])) <= radius_m]
    return max(near, key=lambda c: (c.inliers, c.similarity)) if near else best


def _unique_goal_points(parts: list[tuple[NDArray[np.int64], NDArray[np.float64]]]
                        ) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """(goal keypoint indices (M,), 3D points (M, 3)) pooled from several keyframes' lifted
    matches, one point per goal keypoint: the first part's where several keyframes matched it
    (one keypoint is one ray; two points on it would count one observation twice)."""
    i_goal = np.concatenate([p[0] for p in parts])
    pts = np.concatenate([p[1] for p in parts]).reshape(-1, 3)
    _, first = np.unique(i_goal, return_index=True)
    return i_goal[first], pts[first]


def distinctive_support(points_map: NDArray[np.float64], up: NDArray[np.float64], band_m: float) -> int:
    """PnP support points (N, 3, map frame) that say which place an image shows: all but those in
    the densest horizontal band of `band_m` metres (floor or ceiling tiles, which repeat in every
    room and, shifted by a tile, fit at several spots of one room); `band_m` 0: all of them."""
    if band_m <= 0 or len(points_map) == 0:
        return len(points_map)
    return round(len(points_map) * (1.0 - horizontal_share(points_map, up, band_m)))


def _unambiguous(topomap: TopoMap, cands: list[_Candidate], verified: list[_Candidate], best: _Candidate,
                 params: GoalParams, table: tuple[tuple[int, float, int], ...]) -> tuple[_Candidate, GoalResult | None]:
    """The ambiguity test of `localize_goal`: candidates grouped into places; the goal is ambiguous
    when another place's PnP support exceeds 1/`ambiguity_ratio` of the chosen place's, unless
    (`ambiguity_band_m` > 0) one place with a verified candidate holds at least `pose_min_inliers`
    distinctive support points (not on floor or ceiling tiles) and `ambiguity_ratio` times any
    other place's: then that place is chosen. (the chosen candidate, None) or (-, the refusal); where
    the PnP supports single out the place, the candidate is the strongest pose of the group most of
    the place's support agrees with (`_consensus`; inliers and support its own) with `node` set to
    the place's keyframe nearest that pose."""
    covis = topomap.covisibility_lists
    places = _places(cands, params.agree_m, params.agree_deg, topomap.grid.to_plane, lambda a, b: b in covis[a])
    support = [sum(c.pose_inliers for c in p) for p in places]
    mine = next(i for i, p in enumerate(places) if best in p)
    rivals = [(s, p[0]) for i, (s, p) in enumerate(zip(support, places, strict=True)) if i != mine]
    if not rivals or max(r[0] for r in rivals) * params.ambiguity_ratio <= support[mine]:
        # the place's pose comes from the poses most of its support agrees with; the robot drives
        # to the place's keyframe nearest that pose
        seed = _consensus(places[mine], params.agree_m, params.agree_deg, topomap.grid.to_plane)
        assert seed.T_map_goal is not None
        at = seed.T_map_goal[:3, 3]
        pos = np.asarray(topomap.positions, np.float64)
        near = min(places[mine], key=lambda c: float(np.linalg.norm(pos[c.node] - at)))
        return replace(seed, node=near.node), None
    if params.ambiguity_band_m > 0:  # tiles say nothing about the place: does the rest single one out?
        up = topomap.grid.up
        distinct = [distinctive_support(_support_map(topomap, p), up, params.ambiguity_band_m) for p in places]
        ok = [i for i, p in enumerate(places) if any(c in verified for c in p)]  # best's place is one
        w = max(ok, key=lambda i: (distinct[i], best in places[i]))
        other = max((d for i, d in enumerate(distinct) if i != w), default=0)
        if distinct[w] >= params.pose_min_inliers and other * params.ambiguity_ratio <= distinct[w]:
            return max((c for c in places[w] if c in verified), key=lambda c: (c.inliers, c.similarity)), None
    s_rival, rival = max(rivals, key=lambda r: r[0])
    assert rival.T_map_goal is not None and best.T_map_goal is not None
    apart = float(np.linalg.norm(rival.T_map_goal[:3, 3] - best.T_map_goal[:3, 3]))
    why = ""
    flat = horizontal_share(_support_map(topomap, [best]), topomap.grid.up)
    if flat >= 0.5:  # say what the image lacks, so the user can retake it
        why = (f"; {100 * flat:.0f} % of node {best.node}'s support lies on one "
               "horizontal surface (floor or ceiling tiles repeat): an image with more of the "
               "place in view would tell them apart")
    return best, GoalResult(None, best.inliers,
                            f"goal image is ambiguous: it verifies at nodes {best.node} and {rival.node}, "
                            f"{apart:.1f} m apart (PnP support {support[mine]} vs {s_rival}, need "
                            f"x{params.ambiguity_ratio:g}){why}", table, None, best.pose_inliers)


def _support_map(topomap: TopoMap, place: list[_Candidate]) -> NDArray[np.float64]:
    """(N, 3) the PnP support points of a place's candidates in the map frame (metres)."""
    return np.concatenate([c.support_points @ topomap.T_map_camera[c.node][:3, :3].T
                           + topomap.T_map_camera[c.node][:3, 3] for c in place] + [np.zeros((0, 3))])


def against_view_graph(topomap: TopoMap, cost: float, against_deg: float) -> Any:
    """The connectivity graph as a directed CSR matrix whose edge i -> j costs `cost` times its
    length (m) when the way from node i to node j points more than `against_deg` away from both
    keyframes' optical axes: a forward-looking camera driven that way faces away from all that
    the map saw there and cannot localize (a corridor mapped one way round, driven back). Other
    edges, and edges shorter than 1 cm (no direction), keep their length. `cost` 1: the map's
    own (symmetric) matrix."""
    G = topomap.connectivity_csr
    if cost == 1.0:
        return G
    C = G.tocoo()
    i, j, w = C.row, C.col, C.data.astype(np.float64)
    pos = np.asarray(topomap.positions, np.float64)
    axis = np.asarray(topomap.T_map_camera, np.float64)[:, :3, 2]
    d = pos[j] - pos[i]
    length = np.linalg.norm(d, axis=1)
    u = d / np.maximum(length, 1e-12)[:, None]
    facing = np.maximum(np.einsum("ij,ij->i", axis[i], u), np.einsum("ij,ij->i", axis[j], u))
    against = (length >= 0.01) & (facing < np.cos(np.radians(against_deg)))
    return sp.csr_matrix((np.where(against, w * cost, w), (i, j)), shape=G.shape)


def shortest_path(topomap: TopoMap, start: int, goal: int, graph: Any | None = None) -> tuple[list[int], float]:
    """Node sequence start..goal and its length (m) on the connectivity graph; the path is the
    cheapest in `graph` (default: the map's connectivity matrix, costs = metres; see
    `against_view_graph`), its length is always in metres."""
    n = topomap.n_nodes
    if not (0 <= start < n and 0 <= goal < n):
        raise NavigationError(f"node ids must be in 0..{n - 1}, got {start} -> {goal}")
    G = topomap.connectivity_csr
    dist, prev = dijkstra(G if graph is None else graph, directed=True, indices=start, return_predecessors=True)
    if not np.isfinite(dist[goal]):
        raise NavigationError(f"no path from node {start} to node {goal} in the connectivity graph")
    path = [goal]
    while path[-1] != start:
        path.append(int(prev[path[-1]]))
    path.reverse()
    if len(path) < 2:
        return path, 0.0
    w = np.asarray(G[path[:-1], path[1:]]).ravel()
    return path, float(np.where(w <= ZERO_EDGE_M, 0.0, w).sum())


def segment_distance(p: NDArray[np.floating], a: NDArray[np.floating], b: NDArray[np.floating]) -> float:
    """Distance (m) from point p to the segment a-b (3-vectors, same frame)."""
    ab = np.asarray(b, np.float64) - a
    den = float(ab @ ab)
    t = 0.0 if den == 0 else float(np.clip((np.asarray(p, np.float64) - a) @ ab / den, 0.0, 1.0))
    return float(np.linalg.norm(np.asarray(p, np.float64) - (a + t * ab)))


def segment_clear(topomap: TopoMap, a: NDArray[np.floating], b: NDArray[np.floating], radius: float) -> bool:
    """True if a disc of `radius` (m) swept from map point a to b (3-vectors) touches no
    OCCUPIED cell of the map's occupancy grid (cells outside the grid count as free)."""
    g = topomap.grid
    if g.cells.size == 0:
        return True
    pa, pb = g.to_plane(np.stack([np.asarray(a, np.float64)[:3], np.asarray(b, np.float64)[:3]]))
    d = pb - pa
    length = float(np.linalg.norm(d))
    n = max(2, int(np.ceil(length / (g.resolution / 2))) + 1)
    normal = np.array([-d[1], d[0]]) / length if length > 0 else np.array([0.0, 1.0])
    offs = np.linspace(-radius, radius, max(3, int(np.ceil(2 * radius / g.resolution)) + 1))
    pts = (pa + np.linspace(0, 1, n)[:, None] * d)[:, None, :] + offs[None, :, None] * normal
    ij = g.cell_of(pts.reshape(-1, 2))
    H, W = g.cells.shape
    inside = (ij[:, 0] >= 0) & (ij[:, 0] < H) & (ij[:, 1] >= 0) & (ij[:, 1] < W)
    return not bool(np.any(g.cells[ij[inside, 0], ij[inside, 1]] == g.OCCUPIED))


@dataclass(frozen=True)
class NavStatus:
    state: str  # idle | planned | reached | failed
    reason: str
    subgoal: int | None = None
    path: tuple[int, ...] = ()
    remaining_m: float = 0.0
    # (3,) map-frame point to drive to first: the next turn of the grid path to the subgoal node
    # where the straight line there crosses a wall; None: drive to the node
    via: tuple[float, float, float] | None = None


# nearest nodes tried for a plan's start in clear line from the robot (`SubgoalTracker.start_node`)
_START_CANDIDATES = 16


class SubgoalTracker:
    """Follow a node path on the map from fused robot positions (map frame).

    `positions` (N, 3): where the robot should be at each node (default: the keyframes'
    camera centres; the planner service passes the matching base positions)."""

    def __init__(self, topomap: TopoMap, params: TrackerParams = TrackerParams(),
                 positions: NDArray[np.floating] | None = None) -> None:
        self.map = topomap
        self.params = params
        self.positions = np.asarray(topomap.positions if positions is None else positions, np.float64)
        if self.positions.shape != (topomap.n_nodes, 3):
            raise ValueError(f"positions must be ({topomap.n_nodes}, 3), got {self.positions.shape}")
        self.index = NodeIndex(self.positions)
        self.graph = against_view_graph(topomap, params.against_view_cost, params.against_view_deg)
        self.goal: int | None = None
        self.path: list[int] = []
        self.status = NavStatus("idle", "no goal")
        self.replans = 0
        self._seg_start: NDArray[np.float64] | None = None  # where the current path segment starts
        self._via: list[NDArray[np.float64]] = []  # grid-path turns still to drive to before path[0]
        self._via_node: int | None = None  # the subgoal node `_via` leads to
        self._prev_node: int | None = None  # the node last passed (the start node after a plan)
        # metres of each connectivity edge: what the mapping pass drove between consecutive keyframes
        self._edge_m = {(min(i, j), max(i, j)): float(m)
                        for (i, j), m in zip(topomap.conn_edges.tolist(), topomap.conn_metres.tolist(), strict=True)}

    def nearest_node(self, position: NDArray[np.floating]) -> int:
        return self.index.nearest(np.asarray(position, np.float64)[:3])[0]

    def start_node(self, position: NDArray[np.floating]) -> int:
        """Where a plan from `position` (map frame, m) starts: the nearest of the `_START_CANDIDATES`
        nearest nodes whose straight line from the robot crosses no wall on the map's grid, else
        the nearest node. The nearest node alone can lie behind a wall: a robot that had reached
        a goal in a room 1.9 m from a corridor keyframe was planned from the corridor and sent at
        the wall."""
        p = np.asarray(position, np.float64)[:3]
        nearest = self.nearest_node(p)
        if self.map.grid.cells.size == 0 or segment_clear(self.map, p, self.positions[nearest], 0.0):
            return nearest
        k = min(_START_CANDIDATES, len(self.index))
        _, ids = self.index.tree.query(p, k=k)
        for i in np.atleast_1d(ids):
            if segment_clear(self.map, p, self.positions[int(i)], 0.0):
                return int(i)
        return nearest

    def _plan(self, position: NDArray[np.floating]) -> NavStatus:
        assert self.goal is not None
        start = self.start_node(position)
        self._seg_start = np.asarray(position, dtype=np.float64)[:3].copy()
        self._via_node = None
        self._prev_node = None
        try:
            self.path, length = shortest_path(self.map, start, self.goal, self.graph)
        except NavigationError as exc:
            self.status = NavStatus("failed", str(exc))
            return self.status
        self.status = NavStatus("planned", f"path of {len(self.path)} nodes", self.path[0], tuple(self.path), length)
        return self.status

    def set_goal(self, goal: int, position: NDArray[np.floating]) -> NavStatus:
        """Plan from the node nearest to `position` (map frame, metres) to node `goal`."""
        if not 0 <= goal < self.map.n_nodes:
            raise NavigationError(f"goal node {goal} not in the map")
        self.goal = goal
        return self._plan(position)

    def update(self, position: NDArray[np.floating]) -> NavStatus:
        """Advance/replan from a new robot position; returns the current status."""
        if self.goal is None or self.status.state in ("idle", "reached", "failed"):
            return self.status
        p = np.asarray(position, dtype=np.float64)[:3]
        pos = self.positions
        while self.path and np.linalg.norm(pos[self.path[0]] - p) <= self.params.reach_m:
            if len(self.path) > 1 and self.params.clearance_m > 0 and \
                    np.linalg.norm(pos[self.path[0]] - p) > self.params.reach_m / 3 and \
                    not segment_clear(self.map, p, pos[self.path[1]], self.params.clearance_m):
                break  # the way on is blocked from here: get closer to this node first
            self._prev_node = self.path.pop(0)
            self._seg_start = pos[self._prev_node].copy()
        if not self.path:
            self.status = NavStatus("reached", f"within {self.params.reach_m} m of goal node {self.goal}")
            return self.status
        via = self._leg_via(p)
        target = pos[self.path[0]] if via is None else via
        if segment_distance(p, p if self._seg_start is None else self._seg_start, target) > self.params.stray_m:
            self.replans += 1
            return self._plan(p)
        legs = np.vstack([p, *self._via, pos[self.path]])  # (K, 3) the way on, through the grid turns
        rem = float(np.linalg.norm(np.diff(legs, axis=0), axis=1).sum())
        self.status = NavStatus("planned", "following", self.path[0], tuple(self.path), rem,
                                None if via is None else (float(via[0]), float(via[1]), float(via[2])))
        return self.status

    def _leg_via(self, p: NDArray[np.float64]) -> NDArray[np.float64] | None:
        """The next turn (3,) of the grid path to the subgoal node `path[0]` from the robot at `p`
        when the straight line there crosses a wall on the map's grid, else None. Planned once per
        subgoal node (and after a replan); turns within `reach_m` are passed."""
        node = self.path[0]
        if node != self._via_node:
            leg_m = self._edge_m.get((min(node, self._prev_node), max(node, self._prev_node)), 0.0) \
                if self._prev_node is not None else 0.0
            self._via_node, self._via = node, self._grid_turns(p, self.positions[node], leg_m)
        while self._via and np.linalg.norm(self._via[0] - p) <= self.params.reach_m:
            self._seg_start = self._via.pop(0)
        return self._via[0] if self._via else None

    def _grid_turns(self, p: NDArray[np.float64], node_xyz: NDArray[np.float64],
                    leg_m: float = 0.0) -> list[NDArray[np.float64]]:
        """Turns (map frame, at the robot's height) of the grid path from `p` to a node whose
        straight line crosses an occupied cell (a wall, with the door to go out of first beside
        it: a local planner that sees only what is ahead drives into the wall); [] where the line
        is clear, the grid has no path within `leg_detour_m` more than the leg, or the option is
        off. The leg is the straight line, or `leg_m` (m) where longer: the metres the mapping pass
        drove along the edge to the node (consecutive keyframes far apart, the rooms between
        covered by other keyframes: the straight line runs through walls, and the way is the
        long one the mapping robot took). Only a line through a wall counts: a corner or a desk
        the line passes within the robot's radius the local planner steers round itself, and
        grid turns that keep just the robot's radius from it would lead it closer."""
        prm = self.params
        straight = float(np.linalg.norm(node_xyz - p))
        if prm.leg_detour_m <= 0 or straight <= prm.reach_m or \
                segment_clear(self.map, p, node_xyz, 0.0):  # also True on a map without a grid
            return []
        detour = prm.leg_detour_m + max(0.0, leg_m - straight)
        way = plan_approach(self.map.grid, p, node_xyz, replace(prm, approach_detour_m=detour))
        if way.waypoints is None:
            return []
        return [w.copy() for w in way.waypoints[:-1]]
