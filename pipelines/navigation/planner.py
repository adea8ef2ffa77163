"""Where a goal image is on the map (the planner computer's side): `localize_goal`.

The goal image is placed on a map node by VPR top-k retrieval **plus
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
"""

from __future__ import annotations

from collections.abc import Callable

import cv2
import numpy as np
from numpy.typing import NDArray

from litevloc.base.geometry import backproject_pixels, invert, project, transform_points
from litevloc.base.params.navigation import GoalParams
from litevloc.pipelines.guided_matching import mutual_nn_count
from litevloc.pipelines.navigation.candidates import Candidate, GoalPose, GoalResult, distinctive_support, plane_rms
from litevloc.pipelines.navigation.graph import segment_clear
from litevloc.pipelines.navigation.places import unambiguous
from litevloc.pipelines.pnp import solve_pnp
from litevloc.pipelines.topomap.types import FeatureSet, TopoMap

MatchFn = Callable[[FeatureSet, FeatureSet], tuple[NDArray[np.int64], NDArray[np.int64]]]


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


def _neighbours(topomap: TopoMap, cands: list[Candidate], params: GoalParams) -> list[int]:
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

    def judge(node: int, n_e: int, gp: GoalPose) -> Candidate:
        T_map_goal = None if gp.T_node_goal is None else topomap.T_map_camera[node] @ gp.T_node_goal
        if T_map_goal is not None and params.pose_min_distinct > 0:
            distinct = distinctive_support(transform_points(topomap.T_map_camera[node], gp.support_points),
                                           topomap.grid.up, params.ambiguity_band_m)
            if distinct < params.pose_min_distinct:  # tiles repeat in every room: they verify no place
                return Candidate(node, float(sims[node]), n_e, None, gp.inliers, tiles=(distinct, gp.inliers))
        doubt = "" if T_map_goal is None else pose_doubt(topomap, node, T_map_goal, K_goal, gp.inliers, params)
        if doubt:
            return Candidate(node, float(sims[node]), n_e, None, gp.inliers, pose_doubt=doubt)
        return Candidate(node, float(sims[node]), n_e, T_map_goal, gp.inliers, gp.plane_rms_m, gp.support_points)

    def verify(node: int) -> Candidate:
        feats, K_node = topomap.features[node], topomap.K[node]
        pairs = match(goal_feats, feats)
        n_e = essential_inliers(goal_feats, K_goal, feats, K_node, match, params, pairs)
        depth = topomap.keypoint_depth(node)
        if depth is None:
            return judge(node, n_e, GoalPose(None, 0))
        i_goal, pts = lift_matches(feats, depth, K_node, pairs)
        lifted[node] = (n_e, i_goal, transform_points(topomap.T_map_camera[node], pts))
        return judge(node, n_e, goal_pose(goal_feats, K_goal, i_goal, pts, params))

    def pooled(c: Candidate) -> Candidate:
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
        return _unverified(strongest, params, table)
    best = max(verified, key=lambda c: (c.inliers, c.similarity))
    if best.T_map_goal is None and not best.pose_doubt and params.pose_fallback_m > 0:
        best = _posed_neighbour(topomap, verified, best, params.pose_fallback_m)
    if best.T_map_goal is None and params.require_pose and (best.pose_doubt
                                                             or topomap.keypoint_depth(best.node) is not None):
        return _no_pose(best, params, table)
    if best.T_map_goal is not None and params.ambiguity_ratio > 0:
        best, refusal = unambiguous(topomap, cands, verified, best, params, table)
        if refusal is not None:
            return refusal
    return GoalResult(best.node, best.inliers, "ok", table, best.T_map_goal, best.pose_inliers)


def _unverified(strongest: Candidate, params: GoalParams, table: tuple[tuple[int, float, int], ...]) -> GoalResult:
    """The refusal of a goal no candidate verifies, saying why the strongest did not: tiles
    alone, flat support short of its bar, or too few inliers."""
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


def _no_pose(best: Candidate, params: GoalParams, table: tuple[tuple[int, float, int], ...]) -> GoalResult:
    """The refusal of a goal that verifies at `best` but gets no metric pose there (`require_pose`)."""
    why = (f": {best.pose_doubt}" if best.pose_doubt else
           f" (PnP: {best.pose_inliers} inliers, need {params.pose_min_inliers} and a pose within "
           f"{params.pose_max_m:g} m of the keyframe): where it was taken, and whether another place fits as "
           "well, cannot be checked")
    return GoalResult(None, best.inliers, f"goal image verifies at node {best.node} ({best.inliers} inliers) but "
                      f"gives no metric pose there{why}", table, None, best.pose_inliers)


def _posed_neighbour(topomap: TopoMap, verified: list[Candidate], best: Candidate, radius_m: float) -> Candidate:
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
