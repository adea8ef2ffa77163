"""Walls as landmarks (`slam.planes`): vertical planes in the keyframes' depth, one landmark
per wall that several keyframes see, as GTSAM `OrientedPlane3Factor`s in the final optimisation.

A corridor driven once each way is held only by the chain of visual edges between its ends; each
edge's rotation is a little off and the corridor bows. Its walls are long planes that every
keyframe along it sees: one plane variable per wall ties those keyframes' sideways position and
heading to one surface, which chained edges cannot do.

1. `wall_planes`: per keyframe, RANSAC over its depth points (camera frame) for planes whose
   normal is horizontal (hypotheses from two points and the up direction), refitted to their
   inliers; the largest first, up to `max_per_keyframe`, each at least `min_width_m` wide
   along the floor and `min_height_m` high. Planes are `n . p + d = 0` with `n` toward the
   camera (d > 0), as GTSAM's `OrientedPlane3`.
2. `associate`: keyframes in id order, their planes moved into the map frame with the poses of
   the first optimisation; an observation joins the wall whose normal is within
   `match_angle_deg`, whose plane passes within `match_offset_m` of the observation's centre,
   and whose extent along the floor overlaps the observation's (or is within `match_gap_m`);
   else it starts a wall. Walls seen from fewer than `min_keyframes` keyframes are dropped.
3. `plane_factors`: one `OrientedPlane3` variable per wall (initialised at its mean plane) and
   one factor per observation (sigmas `sigma_normal_rad`, `sigma_offset_m`).

The optimisation with these factors (`graph.reoptimise`) runs twice: observations whose factor
error then exceeds `outlier_error` (a wrong association, a door, a person) are dropped before
the second solve.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import gtsam
import numpy as np
from numpy.typing import NDArray

from litevloc.base.params.slam import SlamGraphParams, SlamPlaneParams
from litevloc.pipelines.slam.graph import GraphNode, GraphResult, pose_key, reoptimise
from litevloc.pipelines.slam.level import LevelFloor
from litevloc.pipelines.slam.types import F64, Edge


@dataclass(frozen=True)
class PlaneObservation:
    """A wall seen from one keyframe: unit normal `n` (3,) toward the camera and offset `d`
    (metres) of `n . p + d = 0` in the camera frame, its inliers' centre (3,, camera frame),
    their extent along the floor direction `up x n` from the centre (`lo` <= 0 <= `hi`, metres),
    their height span (metres) and count."""

    n: F64
    d: float
    centre: F64
    lo: float
    hi: float
    height_m: float
    points: int


@dataclass
class Wall:
    """A plane landmark: `n` (3,) and `d` of `n . p + d = 0` in the map frame, its extent
    [s0, s1] along the floor direction `up x n` (metres), its (keyframe id, observation)s and
    the sum of their centres (3,), map frame: `d` passes through their mean."""

    n: F64
    d: float
    s0: float
    s1: float
    members: list[tuple[int, PlaneObservation]]
    centre_sum: F64


def _normal(q: F64, c: F64) -> F64:
    """Unit normal of the least-squares plane through points `q` (N, 3) with centre `c`."""
    d = q - c
    return np.asarray(np.linalg.eigh(d.T @ d)[1][:, 0], np.float64)


def _inlier_bound(points: F64, params: SlamPlaneParams) -> F64:
    return params.inlier_m + params.inlier_per_m2 * points[:, 2] ** 2


def wall_planes(points: NDArray[np.floating[Any]], up_camera: F64, params: SlamPlaneParams,
                seed: int = 0) -> list[PlaneObservation]:
    """Vertical planes in one keyframe's depth points ((N, 3), camera frame, metres; NaN rows
    ignored); `up_camera` (3,) the map's up in the camera frame. See the module docstring."""
    p = np.asarray(points, np.float64)
    p = p[np.all(np.isfinite(p), axis=1) & (p[:, 2] > 0) & (p[:, 2] <= params.max_depth_m)]
    up = np.asarray(up_camera, np.float64) / np.linalg.norm(up_camera)
    rng = np.random.default_rng(seed)
    max_tilt = np.sin(np.radians(params.max_tilt_deg))
    out: list[PlaneObservation] = []
    for _ in range(params.max_per_keyframe * 2):
        if len(out) >= params.max_per_keyframe or len(p) < params.min_points:
            break
        bound = _inlier_bound(p, params)
        pairs = rng.integers(len(p), size=(params.ransac_iterations, 2))
        v = p[pairs[:, 1]] - p[pairs[:, 0]]
        v -= np.outer(v @ up, up)
        length = np.linalg.norm(v, axis=1)
        ok = length > 0.2  # two points too close along the floor give no direction
        if not ok.any():
            break
        n = np.cross(up, v[ok] / length[ok, None])
        d = -np.einsum("ij,ij->i", n, p[pairs[ok, 0]])
        support = np.abs(p @ n.T + d) < bound[:, None]  # (N, hypotheses)
        best = int(np.argmax(support.sum(axis=0)))
        inl = support[:, best]
        if inl.sum() < params.min_points:
            break
        plane = _fit(p[inl], up, max_tilt, p, bound, params)
        if plane is None:
            p = p[~inl]
            continue
        obs, used = plane
        if obs is not None:
            out.append(obs)
        p = p[~used]
    return out


def _fit(q: F64, up: F64, max_tilt: float, p: F64, bound_p: F64,
         params: SlamPlaneParams) -> tuple[PlaneObservation | None, NDArray[np.bool_]] | None:
    """The least-squares plane of a hypothesis' inliers `q`; None if it is not vertical. Else the
    observation (None when too small) and the mask of `p`'s points it explains (`bound_p`: each
    point's inlier distance, m)."""
    c = q.mean(axis=0)
    n = _normal(q, c)
    if abs(float(n @ up)) > max_tilt:
        return None
    if float(n @ c) > 0:  # toward the camera: d = -n . c > 0
        n = -n
    dist = np.abs(p @ n - float(n @ c))
    q = p[dist < bound_p]
    # the wall's noisier points go with it, or they come back as a second, tilted copy of it
    used = dist < 3 * bound_p
    if len(q) < params.min_points:
        return None, used
    c = q.mean(axis=0)
    n2 = _normal(q, c)
    if float(n2 @ n) < 0:
        n2 = -n2
    along = (q - c) @ np.cross(up, n2)
    height_m = float(np.ptp(q @ up))
    if float(np.ptp(along)) < params.min_width_m or height_m < params.min_height_m:
        return None, used
    return PlaneObservation(n2, float(-n2 @ c), c, float(along.min()), float(along.max()), height_m,
                            len(q)), used


def associate(observations: Mapping[int, Sequence[PlaneObservation]], poses: Mapping[int, F64], up: F64,
              params: SlamPlaneParams) -> list[Wall]:
    """Walls (map frame) from the keyframes' plane observations (keyframe id -> observations)
    and their poses (id -> 4x4 T_map_camera); see the module docstring. Keyframes without a pose
    are skipped."""
    u = np.asarray(up, np.float64) / np.linalg.norm(up)
    cos_max = np.cos(np.radians(params.match_angle_deg))
    walls: list[Wall] = []
    normals = np.zeros((0, 3))  # the walls' n, d and extents as arrays, to test all walls at once
    geo = np.zeros((0, 3))  # (d, s0, s1)
    for kid in sorted(observations):
        T = poses.get(kid)
        if T is None:
            continue
        R, t = np.asarray(T, np.float64)[:3, :3], np.asarray(T, np.float64)[:3, 3]
        for o in observations[kid]:
            n = R @ o.n
            c = R @ o.centre + t
            off = np.abs(normals @ c + geo[:, 0])
            s = np.cross(u, normals) @ c  # the centre along each wall
            ok = ((normals @ n >= cos_max) & (off <= params.match_offset_m)
                  & (s + o.hi >= geo[:, 1] - params.match_gap_m) & (s + o.lo <= geo[:, 2] + params.match_gap_m))
            if not ok.any():
                s_own = float(c @ np.cross(u, n))
                walls.append(Wall(n, float(-n @ c), s_own + o.lo, s_own + o.hi, [(kid, o)], c.copy()))
                normals = np.vstack([normals, n])
                geo = np.vstack([geo, [walls[-1].d, walls[-1].s0, walls[-1].s1]])
                continue
            j = int(np.flatnonzero(ok)[np.argmin(off[ok])])
            w = walls[j]
            w.members.append((kid, o))
            w.centre_sum = w.centre_sum + c
            m = w.n * (len(w.members) - 1) + n  # running mean of the normals
            w.n = m / np.linalg.norm(m)
            w.d = float(-(w.centre_sum / len(w.members)) @ w.n)
            sw = float(c @ np.cross(u, w.n))
            w.s0, w.s1 = min(w.s0, sw + o.lo), max(w.s1, sw + o.hi)
            normals[j], geo[j] = w.n, (w.d, w.s0, w.s1)
    return [w for w in walls if len({k for k, _ in w.members}) >= params.min_keyframes]


@dataclass(frozen=True, eq=False)
class WallFactors:
    """Wall factors as arrays (what `save_graph` keeps): `observations` (M, 6) rows of (keyframe
    id, wall index, plane n (3), d) in the keyframe's camera frame; `walls` (W, 4) each wall's
    initial plane (n, d) in the map frame."""

    observations: F64
    walls: F64

    @property
    def count(self) -> int:
        return len(self.observations)


def wall_factors(walls: Sequence[Wall]) -> WallFactors:
    """The observations of `walls` (each keyframe posed: `associate` skips the others), as arrays."""
    rows = [[kid, i, *o.n, o.d] for i, w in enumerate(walls) for kid, o in w.members]
    return WallFactors(np.asarray(rows, np.float64).reshape(-1, 6),
                       np.asarray([[*w.n, w.d] for w in walls], np.float64).reshape(-1, 4))


def wall_graph(factors: WallFactors, params: SlamPlaneParams) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
    """One `OrientedPlane3` variable (key `gtsam.symbol("w", i)`) per wall that has an
    observation, one `OrientedPlane3Factor` per observation on the keyframe's pose (`pose_key`)."""
    noise = gtsam.noiseModel.Diagonal.Sigmas(
        np.array([params.sigma_normal_rad, params.sigma_normal_rad, params.sigma_offset_m]))
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    for i in sorted({int(w) for w in factors.observations[:, 1]}):
        n, d = factors.walls[i, :3], factors.walls[i, 3]
        values.insert(int(gtsam.symbol("w", i)), gtsam.OrientedPlane3(gtsam.Unit3(np.asarray(n, float)), float(d)))
    for row in factors.observations:
        graph.add(gtsam.OrientedPlane3Factor(np.asarray(row[2:6], float), noise, pose_key(int(row[0])),
                                             int(gtsam.symbol("w", int(row[1])))))
    return graph, values


@dataclass(frozen=True, eq=False)
class WallResult:
    """What the walls did: plane observations found, walls made (seen from enough keyframes),
    the factors kept in the final solve, and how many were dropped as outliers after the first."""

    observations: int
    walls: int
    factors: WallFactors
    outliers: int

    def as_dict(self) -> dict[str, int]:
        return {"observations": self.observations, "walls": self.walls, "factors": self.factors.count,
                "outliers_dropped": self.outliers}


def optimise_with_walls(keyframes: Sequence[GraphNode], clouds: Mapping[int, NDArray[np.floating[Any]]],
                        edges: list[Edge], result: GraphResult, T_map_first: F64, up: F64,
                        graph_params: SlamGraphParams, params: SlamPlaneParams,
                        level: LevelFloor | None = None) -> tuple[GraphResult, WallResult]:
    """`result` (from `graph.optimise`) solved again with the walls: planes from each keyframe's
    depth points (`clouds`: id -> (N, 3) camera frame), associated by `result`'s poses, as
    factors; one outlier round (see the module docstring). `up` (3,) in the map frame."""
    u = np.asarray(up, np.float64) / np.linalg.norm(up)
    observations = {kid: wall_planes(clouds[kid], np.asarray(T, np.float64)[:3, :3].T @ u, params, seed=kid)
                    for kid, T in result.poses.items() if kid in clouds}
    n_obs = sum(len(v) for v in observations.values())
    walls = associate(observations, result.poses, u, params)
    factors = wall_factors(walls)
    if factors.count == 0:
        return result, WallResult(n_obs, len(walls), factors, 0)
    graph, values = wall_graph(factors, params)
    first, solved = reoptimise(keyframes, edges, result, T_map_first, graph_params, level, graph, values)
    keep = np.array([graph.at(i).error(solved) <= params.outlier_error for i in range(graph.size())], bool)
    if keep.all():
        return first, WallResult(n_obs, len(walls), factors, 0)
    kept = WallFactors(factors.observations[keep], factors.walls)
    return resolve_with_walls(keyframes, edges, result, T_map_first, graph_params, params, kept, level), \
        WallResult(n_obs, len(walls), kept, int((~keep).sum()))


def resolve_with_walls(keyframes: Sequence[GraphNode], edges: list[Edge], result: GraphResult, T_map_first: F64,
                       graph_params: SlamGraphParams, params: SlamPlaneParams, factors: WallFactors,
                       level: LevelFloor | None = None) -> GraphResult:
    """`result` solved again with given wall factors (the final solve of `optimise_with_walls`;
    a saved graph's walls re-solve to the same map with it)."""
    if factors.count == 0:
        return result
    graph, values = wall_graph(factors, params)
    return reoptimise(keyframes, edges, result, T_map_first, graph_params, level, graph, values)[0]
