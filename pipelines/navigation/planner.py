"""Image-goal navigation on the connectivity graph (the planner computer's side).

* `localize_goal`: the goal image is placed on a map node by VPR top-k retrieval **plus
  geometric verification** (the published research code takes VPR top-1 unchecked): the
  goal's features are matched to each candidate keyframe's cached features and an
  essential matrix is fitted with RANSAC; the candidate with most inliers wins if it has
  at least `min_inliers`. A goal that matches no place is reported as such.
* `shortest_path`: Dijkstra on the connectivity graph (edge weights in metres) with the
  standard library's binary heap — the graph has tens to hundreds of nodes, so a graph
  library would add a dependency for no measurable gain.
* `SubgoalTracker`: follows the path node by node, advancing when the robot is within
  `reach_m` of the current subgoal, replanning from the nearest node when the robot strays
  farther than `stray_m` from the path, and reporting idle/planned/reached/failed.
"""

from __future__ import annotations

import heapq
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from litevloc.pipelines.topomap.types import FeatureSet, TopoMap

MatchFn = Callable[[FeatureSet, FeatureSet], tuple[NDArray[np.int64], NDArray[np.int64]]]


class NavigationError(ValueError):
    """No path, bad node ids, or an unusable goal."""


@dataclass(frozen=True)
class GoalParams:
    """Goal localization parameters."""

    top_k: int = 5
    min_inliers: int = 40
    ransac_px: float = 2.0
    seed: int = 0

    def __post_init__(self) -> None:
        if self.top_k < 1 or self.min_inliers < 8 or self.ransac_px <= 0:
            raise ValueError("top_k >= 1, min_inliers >= 8 and ransac_px > 0 required")


@dataclass(frozen=True)
class GoalResult:
    node: int | None
    inliers: int
    reason: str
    candidates: tuple[tuple[int, float, int], ...] = ()  # (node, similarity, inliers)


def essential_inliers(
    f0: FeatureSet, K0: NDArray[np.float64], f1: FeatureSet, K1: NDArray[np.float64], match: MatchFn,
    params: GoalParams,
) -> int:
    """Inliers of an essential matrix (RANSAC) between two images' matched features."""
    i0, i1 = match(f0, f1)
    if len(i0) < 8:
        return 0
    p0 = cv2.undistortPoints(np.asarray(f0.keypoints, np.float64)[i0].reshape(-1, 1, 2), K0, None).reshape(-1, 2)
    p1 = cv2.undistortPoints(np.asarray(f1.keypoints, np.float64)[i1].reshape(-1, 1, 2), K1, None).reshape(-1, 2)
    focal = 0.5 * (K0[0, 0] + K1[0, 0])
    cv2.setRNGSeed(params.seed)
    E, mask = cv2.findEssentialMat(p0, p1, np.eye(3), method=cv2.RANSAC, prob=0.999,
                                   threshold=params.ransac_px / focal)
    return 0 if E is None or mask is None else int(mask.sum())


def localize_goal(
    goal_feats: FeatureSet, goal_desc: NDArray[np.float32], K_goal: NDArray[np.float64], topomap: TopoMap,
    match: MatchFn, params: GoalParams = GoalParams(),
) -> GoalResult:
    """Map node of a goal image, or `node=None` with the reason."""
    sims = topomap.vpr @ np.asarray(goal_desc, np.float32)
    order = np.argsort(-sims, kind="stable")[: params.top_k]
    cands = []
    for node in order:
        n = essential_inliers(goal_feats, K_goal, topomap.features[int(node)], topomap.K[int(node)], match, params)
        cands.append((int(node), float(sims[node]), n))
    best = max(cands, key=lambda c: (c[2], c[1]))
    if best[2] < params.min_inliers:
        return GoalResult(None, best[2], f"goal image matches no map place (best {best[2]} inliers < "
                          f"{params.min_inliers})", tuple(cands))
    return GoalResult(best[0], best[2], "ok", tuple(cands))


def shortest_path(topomap: TopoMap, start: int, goal: int) -> tuple[list[int], float]:
    """Node sequence start..goal and its length (m) on the connectivity graph."""
    n = topomap.n_nodes
    if not (0 <= start < n and 0 <= goal < n):
        raise NavigationError(f"node ids must be in 0..{n - 1}, got {start} -> {goal}")
    adj: list[list[tuple[int, float]]] = [[] for _ in range(n)]
    for (i, j), w in zip(topomap.conn_edges, topomap.conn_metres, strict=True):
        adj[int(i)].append((int(j), float(w)))
        adj[int(j)].append((int(i), float(w)))
    dist = np.full(n, np.inf)
    prev = np.full(n, -1, dtype=np.int64)
    dist[start] = 0.0
    heap = [(0.0, start)]
    while heap:
        d, u = heapq.heappop(heap)
        if d > dist[u]:
            continue
        if u == goal:
            break
        for v, w in adj[u]:
            if d + w < dist[v]:
                dist[v] = d + w
                prev[v] = u
                heapq.heappush(heap, (d + w, v))
    if not np.isfinite(dist[goal]):
        raise NavigationError(f"no path from node {start} to node {goal} in the connectivity graph")
    path = [goal]
    while path[-1] != start:
        path.append(int(prev[path[-1]]))
    return path[::-1], float(dist[goal])


@dataclass(frozen=True)
class TrackerParams:
    reach_m: float = 0.5
    stray_m: float = 2.0

    def __post_init__(self) -> None:
        if self.reach_m <= 0 or self.stray_m <= self.reach_m:
            raise ValueError("need 0 < reach_m < stray_m")


@dataclass(frozen=True)
class NavStatus:
    state: str  # idle | planned | reached | failed
    reason: str
    subgoal: int | None = None
    path: tuple[int, ...] = ()
    remaining_m: float = 0.0


class SubgoalTracker:
    """Follow a node path on the map from fused robot positions (map frame)."""

    def __init__(self, topomap: TopoMap, params: TrackerParams = TrackerParams()) -> None:
        self.map = topomap
        self.params = params
        self.goal: int | None = None
        self.path: list[int] = []
        self.status = NavStatus("idle", "no goal")
        self.replans = 0

    def nearest_node(self, position: NDArray[np.floating]) -> int:
        return int(np.argmin(np.linalg.norm(self.map.positions - np.asarray(position)[:3], axis=1)))

    def _plan(self, position: NDArray[np.floating]) -> NavStatus:
        assert self.goal is not None
        start = self.nearest_node(position)
        try:
            self.path, length = shortest_path(self.map, start, self.goal)
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
        pos = self.map.positions
        while self.path and np.linalg.norm(pos[self.path[0]] - p) <= self.params.reach_m:
            self.path.pop(0)
        if not self.path:
            self.status = NavStatus("reached", f"within {self.params.reach_m} m of goal node {self.goal}")
            return self.status
        if np.linalg.norm(pos[self.path[0]] - p) > self.params.stray_m:
            self.replans += 1
            return self._plan(p)
        rem = float(np.linalg.norm(pos[self.path[0]] - p)) + float(
            sum(np.linalg.norm(pos[a] - pos[b]) for a, b in zip(self.path[:-1], self.path[1:], strict=True))
        )
        self.status = NavStatus("planned", "following", self.path[0], tuple(self.path), rem)
        return self.status
