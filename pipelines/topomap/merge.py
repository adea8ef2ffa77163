"""Join map sessions recorded in different world frames (`litevloc map merge A B -o MERGED`).

Each session's map is metric and consistent in its own frame (its own odometry/SLAM
origin). To join session B to session A:

1. **Landmarks in B** (`node_landmarks`): a B keyframe's keypoints are triangulated with
   its strongest covisible neighbours in B (known relative pose, metric), giving 3D points
   in B's frame — maps store keypoints and poses, not depth.
2. **Cross-session links** (`find_links`): each B keyframe's VPR top-k A keyframes are
   matched to it; B's landmarks and their A pixels give a PnP + RANSAC pose
   `T_Ai_B` (B frame -> A keyframe camera), hence one estimate of `T_A_B` per link.
3. **Robust alignment** (`align`): GTSAM's graduated non-convexity (GNC, truncated least
   squares) over one `Pose3` with a prior factor per link: wrong links (repetitive
   places, VPR confusions) get weight 0 instead of bending the alignment. Refused with the
   reason when fewer than `min_links` links agree.
4. **Join** (`join_maps`): B's nodes re-expressed in A's frame, occupancy grids fused on
   A's ground plane, covisibility edges for the verified links, connectivity edges across
   sessions where the straight way is free, and B keyframes that duplicate an A keyframe's
   place (position and viewing direction) dropped, their edges handed to the A keyframe.

Pure: maps and an injected matcher in, a map out. Frames: `T_A_B` maps points of B's map
frame into A's map frame; node poses are `T_map_camera`.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import gtsam
import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from litevloc.base.errors import LiteVLocError
from litevloc.base.geometry import invert, relative_pose_error
from litevloc.base.params.map_maintenance import MergeParams
from litevloc.pipelines.pnp import solve_pnp
from litevloc.pipelines.topomap.graphs import MatchFn
from litevloc.pipelines.topomap.occupancy import segment_is_free
from litevloc.pipelines.topomap.types import OccupancyGrid, TopoMap


class MapMergeError(LiteVLocError, ValueError):
    """Two sessions cannot be merged (too little overlap, other models, other ground planes)."""


@dataclass(frozen=True, eq=False)
class Link:
    """One verified cross-session correspondence: A node `a` sees B node `b`'s landmarks."""

    a: int
    b: int
    T_A_B: NDArray[np.float64]  # 4x4, this link's estimate of the frame alignment
    inliers: int
    similarity: float


@dataclass(frozen=True, eq=False)
class Alignment:
    """Robust frame alignment of B to A and which links agree with it."""

    T_A_B: NDArray[np.float64]  # 4x4
    consistent: NDArray[np.bool_]  # (L,) per link
    residual_m: NDArray[np.float64]  # (L,) translation of each link's estimate from T_A_B at B's nodes
    residual_deg: NDArray[np.float64]  # (L,)


@dataclass(frozen=True)
class MergeReport:
    """What a merge did, for the CLI and the manifest."""

    links_tried: int
    links_verified: int
    links_consistent: int
    nodes_a: int
    nodes_b: int
    nodes_dropped: int
    nodes_merged: int
    cross_covisibility_edges: int
    cross_connectivity_edges: int
    T_A_B: tuple[tuple[float, ...], ...]


# ---------------------------------------------------------------------- frames
def transform_map(m: TopoMap, T_new_old: NDArray[np.float64]) -> TopoMap:
    """The same map re-expressed in another frame: node poses `T_new_old @ T_old_camera`,
    the grid's `up` and plane axes rotated and its origin shifted (cells unchanged)."""
    T = np.asarray(T_new_old, dtype=np.float64)
    R, t = T[:3, :3], T[:3, 3]
    g = m.grid
    axes = g.plane_axes @ R.T  # (2, 3): rows rotated into the new frame
    grid = OccupancyGrid(g.cells, g.origin + axes @ t, g.resolution, R @ g.up, axes)
    T_map_camera: NDArray[np.float64] = np.einsum("ij,njk->nik", T, m.T_map_camera)
    return dataclasses.replace(m, T_map_camera=T_map_camera, grid=grid)


# ---------------------------------------------------------------------- landmarks
def _neighbours(m: TopoMap) -> list[list[int]]:
    out: list[list[tuple[float, int]]] = [[] for _ in range(m.n_nodes)]
    for (i, j), w in zip(m.covis_edges.tolist(), m.covis_weight.tolist(), strict=True):
        out[i].append((-w, j))
        out[j].append((-w, i))
    return [[n for _, n in sorted(v)] for v in out]


def node_landmarks(
    m: TopoMap, node: int, match: MatchFn, params: MergeParams, neighbours: list[int] | None = None,
) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """Keypoints of `node` triangulated with its covisible neighbours: (ids (n,), points (n, 3)
    in the map frame). A keypoint seen by several neighbours keeps the widest-parallax point."""
    nb = neighbours if neighbours is not None else _neighbours(m)[node]
    T_c0 = invert(m.T_map_camera[node])
    P0 = m.K[node] @ T_c0[:3]
    f0 = m.features[node]
    best: dict[int, tuple[float, NDArray[np.float64]]] = {}
    for other in nb[: params.landmark_neighbours]:
        i0, i1 = match(f0, m.features[other])
        if len(i0) < 8:
            continue
        T_c1 = invert(m.T_map_camera[other])
        P1 = m.K[other] @ T_c1[:3]
        uv0 = np.asarray(f0.keypoints, np.float64)[i0]
        uv1 = np.asarray(m.features[other].keypoints, np.float64)[i1]
        Xh = cv2.triangulatePoints(P0, P1, uv0.T, uv1.T)
        with np.errstate(divide="ignore", invalid="ignore"):
            X = (Xh[:3] / Xh[3]).T
        ok = np.isfinite(X).all(axis=1)
        c0, c1 = m.T_map_camera[node][:3, 3], m.T_map_camera[other][:3, 3]
        for k in np.nonzero(ok)[0]:
            x = X[k]
            ok_k = True
            for P, T_c, uv in ((P0, T_c0, uv0[k]), (P1, T_c1, uv1[k])):
                pc = T_c[:3, :3] @ x + T_c[:3, 3]
                if pc[2] <= 0.05:
                    ok_k = False
                    break
                proj = (P @ np.append(x, 1.0))
                if np.linalg.norm(proj[:2] / proj[2] - uv) > params.max_triangulation_px:
                    ok_k = False
                    break
            if not ok_k:
                continue
            r0, r1 = x - c0, x - c1
            cosang = float(r0 @ r1 / (np.linalg.norm(r0) * np.linalg.norm(r1) + 1e-12))
            parallax = float(np.degrees(np.arccos(np.clip(cosang, -1.0, 1.0))))
            if parallax < params.min_parallax_deg:
                continue
            kp = int(i0[k])
            if kp not in best or parallax > best[kp][0]:
                best[kp] = (parallax, x)
    ids = np.asarray(sorted(best), dtype=np.int64)
    pts = np.asarray([best[int(k)][1] for k in ids], dtype=np.float64).reshape(-1, 3)
    return ids, pts


# ---------------------------------------------------------------------- links
def find_links(
    A: TopoMap, B: TopoMap, match: MatchFn, params: MergeParams,
    on_node: Callable[[], None] | None = None,
) -> tuple[list[Link], int]:
    """Verified cross-session links (and how many candidate pairs were tried)."""
    if A.vpr.shape[1] != B.vpr.shape[1]:
        raise MapMergeError(f"VPR descriptors differ in size ({A.vpr.shape[1]} vs {B.vpr.shape[1]})")
    nb_B = _neighbours(B)
    links: list[Link] = []
    tried = 0
    sims_all = B.vpr @ A.vpr.T  # (nB, nA)
    for b in range(B.n_nodes):
        if on_node is not None:
            on_node()
        ids, X_B = node_landmarks(B, b, match, params, nb_B[b])
        if len(ids) < params.min_landmarks:
            continue
        lookup = {int(k): r for r, k in enumerate(ids)}
        order = np.argsort(-sims_all[b], kind="stable")[: params.vpr_top_k]
        for a in order.tolist():
            tried += 1
            ib, ia = match(B.features[b], A.features[a])
            rows = [(lookup[int(k)], int(j)) for k, j in zip(ib.tolist(), ia.tolist(), strict=True)
                    if int(k) in lookup]
            if len(rows) < params.min_link_inliers:
                continue
            r = np.asarray(rows, dtype=np.int64)
            res = solve_pnp(X_B[r[:, 0]], np.asarray(A.features[a].keypoints, np.float64)[r[:, 1]], A.K[a],
                            params.pnp)
            if not res.accepted or res.T_target_source is None or res.n_inliers < params.min_link_inliers:
                continue
            T_A_B = A.T_map_camera[a] @ res.T_target_source
            links.append(Link(a, b, T_A_B, res.n_inliers, float(sims_all[b, a])))
    return links, tried


def _pose3(T: NDArray[np.float64]) -> gtsam.Pose3:
    return gtsam.Pose3(gtsam.Rot3(T[:3, :3]), np.array(T[:3, 3], dtype=float))


def robust_alignment(
    estimates: list[NDArray[np.float64]], at: list[NDArray[np.float64]], weights: list[int], params: MergeParams,
    what: str = "cross-session links",
) -> Alignment:
    """Robust frame alignment `T_A_B` from several estimates (GTSAM GNC, truncated least squares).

    Args:
        estimates: 4x4 estimates of `T_A_B`, one per correspondence.
        at: 4x4 pose in frame B where each estimate was made (a B keyframe, a session frame):
            consistency is judged there, as the pose mapped by the estimate vs by the result.
        weights: e.g. inlier counts; the largest gives the initial guess.
    """
    if len(estimates) < params.min_links:
        raise MapMergeError(
            f"the sessions do not overlap enough to align: {len(estimates)} verified {what} (< {params.min_links})")
    sig = np.array([np.radians(params.link_sigma_deg)] * 3 + [params.link_sigma_m] * 3)
    noise = gtsam.noiseModel.Diagonal.Sigmas(sig)
    key = gtsam.symbol("x", 0)
    graph = gtsam.NonlinearFactorGraph()
    for T_est in estimates:
        graph.add(gtsam.PriorFactorPose3(key, _pose3(T_est), noise))
    init = gtsam.Values()
    init.insert(key, _pose3(estimates[int(np.argmax(weights))]))
    gnc_params = gtsam.GncLMParams()
    gnc_params.setLossType(gtsam.GncLossType.TLS)
    T = gtsam.GncLMOptimizer(graph, init, gnc_params).optimize().atPose3(key).matrix()
    res = np.asarray([relative_pose_error(T_est @ Tb, T @ Tb) for T_est, Tb in zip(estimates, at, strict=True)])
    rm, rd = res[:, 0], res[:, 1]
    ok = (rm <= params.consistent_m) & (rd <= params.consistent_deg)
    if int(ok.sum()) < params.min_links:
        raise MapMergeError(
            f"the sessions do not overlap enough to align: {int(ok.sum())} of {len(estimates)} {what} "
            f"agree (< {params.min_links}); median disagreement {np.median(rm):.2f} m")
    # final estimate over the consistent ones only (plain least squares, no outliers left)
    graph2 = gtsam.NonlinearFactorGraph()
    for T_est, good in zip(estimates, ok.tolist(), strict=True):
        if good:
            graph2.add(gtsam.PriorFactorPose3(key, _pose3(T_est), noise))
    init2 = gtsam.Values()
    init2.insert(key, _pose3(T))
    T = gtsam.LevenbergMarquardtOptimizer(graph2, init2).optimize().atPose3(key).matrix()
    return Alignment(T, ok, rm, rd)


def align(links: list[Link], B: TopoMap, params: MergeParams) -> Alignment:
    """Robust `T_A_B` from the links; a link's consistency is judged at its B keyframe."""
    return robust_alignment([ln.T_A_B for ln in links], [B.T_map_camera[ln.b] for ln in links],
                            [ln.inliers for ln in links], params)


# ---------------------------------------------------------------------- join
def fuse_grids(a: OccupancyGrid, b: OccupancyGrid, params: MergeParams) -> OccupancyGrid:
    """B's grid (already in A's frame) resampled onto an enlarged copy of A's grid.
    Observed beats unknown; occupied beats free (an obstacle seen by either session)."""
    cos = float(np.clip(a.up @ b.up, -1.0, 1.0))
    if np.degrees(np.arccos(cos)) > params.max_up_disagreement_deg:
        raise MapMergeError(f"the sessions' ground planes disagree by {np.degrees(np.arccos(cos)):.1f} deg after "
                            f"alignment (> {params.max_up_disagreement_deg}); check the mapping.up of each")
    res = a.resolution
    # B's observed cell centres in A's plane coordinates (for the extent)
    rows, cols = np.nonzero(b.cells != OccupancyGrid.UNKNOWN)
    xy_b = b.origin + (np.stack([cols, rows], axis=1) + 0.5) * b.resolution
    p3 = xy_b @ b.plane_axes  # points in the map frame on B's plane through the origin
    xy_in_a = p3 @ a.plane_axes.T
    Ha, Wa = a.cells.shape
    lo = np.minimum(a.origin, xy_in_a.min(axis=0) - res if len(xy_in_a) else a.origin)
    hi = np.maximum(a.origin + np.array([Wa, Ha]) * res, xy_in_a.max(axis=0) + res if len(xy_in_a) else a.origin)
    off = np.floor((a.origin - lo) / res).astype(int)  # A's cell (0,0) in the new grid (col, row)
    origin = a.origin - off * res
    W, H = (np.ceil((hi - origin) / res).astype(int)).tolist()
    cells = np.zeros((H, W), np.uint8)
    cells[off[1]: off[1] + Ha, off[0]: off[0] + Wa] = a.cells
    # every new cell's centre looked up in B's grid (inverse mapping: no holes after rotation)
    rr, cc = np.mgrid[0:H, 0:W]
    xy = origin + (np.stack([cc.ravel(), rr.ravel()], axis=1) + 0.5) * res
    in_b = (xy @ a.plane_axes) @ b.plane_axes.T
    ij = np.floor((in_b - b.origin) / b.resolution).astype(int)
    Hb, Wb = b.cells.shape
    inside = (ij[:, 0] >= 0) & (ij[:, 0] < Wb) & (ij[:, 1] >= 0) & (ij[:, 1] < Hb)
    vals = np.zeros(len(xy), np.uint8)
    vals[inside] = b.cells[ij[inside, 1], ij[inside, 0]]
    cells = np.maximum(cells, vals.reshape(H, W))  # UNKNOWN 0 < FREE 1 < OCCUPIED 2
    return OccupancyGrid(cells, origin, res, a.up, a.plane_axes)


def _duplicates(A: TopoMap, B_in_A: TopoMap, params: MergeParams) -> dict[int, int]:
    """B keyframes at an A keyframe's place (position + viewing direction): B node -> the
    nearest such A node."""
    tree_a = cKDTree(A.positions)
    cos_dup = np.cos(np.radians(params.duplicate_angle_deg))
    replace: dict[int, int] = {}
    for b, near in enumerate(tree_a.query_ball_point(B_in_A.positions, r=params.duplicate_radius_m)):
        if not near:
            continue
        zb = B_in_A.T_map_camera[b, :3, 2]
        cand = [(float(np.linalg.norm(A.positions[a] - B_in_A.positions[b])), a) for a in near
                if float(A.T_map_camera[a, :3, 2] @ zb) >= cos_dup]
        if cand:
            replace[b] = min(cand)[1]
    return replace


def _connect_across(grid: OccupancyGrid, xy: NDArray[np.float64], nA: int, tree_b: cKDTree, params: MergeParams,
                    conn: dict[tuple[int, int], list[float]]) -> int:
    """Connectivity edges between A's nodes (xy[:nA], plane metres) and B's kept ones (xy[nA:],
    in `tree_b`) within `connect_m` along free segments, each node's `connect_neighbours`
    nearest; added to `conn` (the shorter length where one exists). Returns the new edges."""
    partners: dict[int, list[tuple[float, int]]] = {}
    for a, near in enumerate(tree_b.query_ball_point(xy[:nA], r=params.connect_m)):
        for k in near:
            j = nA + k
            d = float(np.linalg.norm(xy[a] - xy[j]))
            if segment_is_free(grid, xy[a], xy[j]):
                partners.setdefault(a, []).append((d, j))
                partners.setdefault(j, []).append((d, a))
    chosen: set[tuple[int, int]] = set()
    for i, lst in partners.items():
        for _d, j in sorted(lst)[: params.connect_neighbours]:
            chosen.add((min(i, j), max(i, j)))
    n_new = 0
    for e in sorted(chosen):
        if e not in conn:
            n_new += 1
        d = float(np.linalg.norm(xy[e[0]] - xy[e[1]]))
        conn[e] = [min(conn.get(e, [np.inf])[0], d)]
    return n_new


def join_maps(A: TopoMap, B_in_A: TopoMap, links: list[Link], alignment: Alignment,
              params: MergeParams) -> tuple[TopoMap, MergeReport]:
    """One map from A and B (B already re-expressed in A's frame by `transform_map`)."""
    if A.extractor != B_in_A.extractor or A.vpr_model != B_in_A.vpr_model:
        raise MapMergeError(f"the maps were built with other models ({A.extractor}/{A.vpr_model} vs "
                            f"{B_in_A.extractor}/{B_in_A.vpr_model})")
    nA = A.n_nodes
    grid = fuse_grids(A.grid, B_in_A.grid, params)
    replace = _duplicates(A, B_in_A, params)
    keep_b = [b for b in range(B_in_A.n_nodes) if b not in replace]
    new_id = {b: nA + k for k, b in enumerate(keep_b)}
    new_id.update({b: a for b, a in replace.items()})

    def remap(edges: NDArray[np.int64], vals: list[NDArray[np.generic]], table: dict[int, int] | None,
              acc: dict[tuple[int, int], list[float]], keep: Callable[[float, float], float]) -> None:
        """Add edges (renumbered through `table`) to `acc`; a repeated edge keeps `keep` of each value."""
        for k, (i, j) in enumerate(edges.tolist()):
            ii, jj = (table[i], table[j]) if table is not None else (i, j)
            if ii == jj:
                continue
            e = (min(ii, jj), max(ii, jj))
            row = [float(v[k]) for v in vals]
            acc[e] = row if e not in acc else [keep(x, y) for x, y in zip(acc[e], row, strict=True)]

    covis: dict[tuple[int, int], list[float]] = {}
    remap(A.covis_edges, [A.covis_inliers, A.covis_weight], None, covis, max)
    remap(B_in_A.covis_edges, [B_in_A.covis_inliers, B_in_A.covis_weight], new_id, covis, max)
    n_cross_cov = 0
    for ln, good in zip(links, alignment.consistent.tolist(), strict=True):
        if not good:
            continue
        i, j = ln.a, new_id[ln.b]
        if i == j:
            continue
        e = (min(i, j), max(i, j))
        if e not in covis:
            n_cross_cov += 1
        w = min(ln.inliers / 200.0, 1.0)
        covis[e] = [max(covis.get(e, [0, 0])[0], ln.inliers), max(covis.get(e, [0, 0])[1], w)]
    conn: dict[tuple[int, int], list[float]] = {}
    remap(A.conn_edges, [A.conn_metres], None, conn, min)
    remap(B_in_A.conn_edges, [B_in_A.conn_metres], new_id, conn, min)

    T_all = np.concatenate([A.T_map_camera, B_in_A.T_map_camera[keep_b]])
    xy = grid.to_plane(T_all[:, :3, 3])
    tree_b = cKDTree(xy[nA:]) if len(keep_b) else None
    n_cross_conn = 0 if tree_b is None else _connect_across(grid, xy, nA, tree_b, params, conn)

    def arrays(acc: dict[tuple[int, int], list[float]]) -> tuple[NDArray[np.int64], list[list[float]]]:
        keys = sorted(acc)
        return np.asarray(keys, dtype=np.int64).reshape(-1, 2), [acc[k] for k in keys]

    ce, cv = arrays(covis)
    ne, nv = arrays(conn)
    kb = np.asarray(keep_b, dtype=np.int64)
    meta = dict(A.meta)
    meta["merged_sessions"] = json.dumps([A.meta.get("source", "A"), B_in_A.meta.get("source", "B")])
    merged = TopoMap(
        T_map_camera=T_all,
        K=np.concatenate([A.K, B_in_A.K[kb]]), image_size=np.concatenate([A.image_size, B_in_A.image_size[kb]]),
        t_ns=np.concatenate([A.t_ns, B_in_A.t_ns[kb]]), frame_index=np.concatenate([A.frame_index,
                                                                                       B_in_A.frame_index[kb]]),
        vpr=np.concatenate([A.vpr, B_in_A.vpr[kb]]),
        features=[*(A.stored_features(a) for a in range(nA)), *(B_in_A.stored_features(b) for b in keep_b)],
        images_jpeg=[*A.images_jpeg, *(B_in_A.images_jpeg[b] for b in keep_b)],
        covis_edges=ce, covis_inliers=np.asarray([int(v[0]) for v in cv], np.int32),
        covis_weight=np.asarray([v[1] for v in cv], np.float32),
        conn_edges=ne, conn_metres=np.asarray([v[0] for v in nv], np.float32),
        grid=grid, extractor=A.extractor, vpr_model=A.vpr_model, meta=meta,
    )
    report = MergeReport(
        links_tried=0, links_verified=len(links), links_consistent=int(alignment.consistent.sum()),
        nodes_a=nA, nodes_b=B_in_A.n_nodes, nodes_dropped=len(replace), nodes_merged=merged.n_nodes,
        cross_covisibility_edges=n_cross_cov, cross_connectivity_edges=n_cross_conn,
        T_A_B=tuple(tuple(float(x) for x in row) for row in alignment.T_A_B),
    )
    return merged, report


def merge_sessions(
    A: TopoMap, B: TopoMap, match: MatchFn, params: MergeParams | None = None,
    on_node: Callable[[], None] | None = None,
) -> tuple[TopoMap, MergeReport, Alignment, list[Link]]:
    """Link, align and join session B into session A's frame (see the module docstring)."""
    params = params or MergeParams()
    links, tried = find_links(A, B, match, params, on_node)
    alignment = align(links, B, params)
    merged, report = join_maps(A, transform_map(B, alignment.T_A_B), links, alignment, params)
    report = dataclasses.replace(report, links_tried=tried)
    merged.meta["merge_T_first_second"] = json.dumps([list(r) for r in report.T_A_B])
    merged.meta["merge_links"] = f"{report.links_consistent}/{report.links_verified}"
    _check_consistent(merged)
    return merged, report, alignment, links


def _check_consistent(m: TopoMap) -> None:
    """Refuse a merge result that is not a valid map (edges out of range, self loops, ...)."""
    n = m.n_nodes
    for name, e in (("covisibility", m.covis_edges), ("connectivity", m.conn_edges)):
        if len(e) and (e.min() < 0 or e.max() >= n or np.any(e[:, 0] >= e[:, 1])):
            raise MapMergeError(f"merge produced invalid {name} edges (internal error)")
    if not (len(m.K) == len(m.vpr) == len(m.features) == len(m.images_jpeg) == n):
        raise MapMergeError("merge produced arrays of different lengths (internal error)")
    R = m.T_map_camera[:, :3, :3]
    if not np.allclose(R @ R.transpose(0, 2, 1), np.eye(3), atol=1e-6):
        raise MapMergeError("merge produced a non-rigid node pose (internal error)")
