"""Spatial and graph indexes over a map's nodes, built once per map.

* `NodeIndex`: a KD-tree (`scipy.spatial.cKDTree`) over node positions (N, 3) in the
  map frame, metres: nearest node and nodes within a radius in O(log N + k) instead of a
  linear scan. `local_candidates` is the localizer's LL candidate rule on top of it.
* `neighbour_lists`: per-node neighbour lists of an undirected weighted edge list
  (strongest edge first, ties by node id), from one lexsort instead of a per-node scan.
* `connectivity_matrix`: the connectivity graph as a symmetric `scipy.sparse` CSR matrix
  for `scipy.sparse.csgraph` shortest paths (duplicate edges keep their shortest length;
  zero-length edges stay edges).

Ties are resolved as the brute-force code does (`np.argmin`: the lowest node id among
equally near nodes), so results are identical to a linear scan.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray
from scipy.spatial import cKDTree

# Zero-length connectivity edges would vanish from a sparse matrix (an explicit zero is
# "no edge" to csgraph); they are stored as this many metres instead and the path length
# is recomputed from the true edge lengths.
ZERO_EDGE_M = 1e-9


class NodeIndex:
    """KD-tree over node positions.

    positions: (N, 3) float, map frame, metres (N >= 1). Queries take a 3-vector."""

    def __init__(self, positions: NDArray[np.floating]) -> None:
        pos = np.asarray(positions, dtype=np.float64)
        if pos.ndim != 2 or pos.shape[1] != 3 or len(pos) < 1:
            raise ValueError(f"positions must be (N >= 1, 3), got {pos.shape}")
        if not np.all(np.isfinite(pos)):
            raise ValueError("positions must be finite")
        self.positions = pos
        self.tree = cKDTree(pos)

    def __len__(self) -> int:
        return len(self.positions)

    def nearest(self, point: NDArray[np.floating]) -> tuple[int, float]:
        """(node id, distance in m) of the node nearest to `point` (lowest id on ties)."""
        p = np.asarray(point, dtype=np.float64)[:3]
        d, i = self.tree.query(p, k=1)
        d = float(d)
        # cKDTree returns any of several equidistant nodes: take the lowest id, as argmin does.
        tied = self.tree.query_ball_point(p, d * (1 + 1e-12) + 1e-15)
        if len(tied) > 1:
            dist = np.linalg.norm(self.positions[tied] - p, axis=1)
            dmin = dist.min()
            i = min(int(t) for t, dt in zip(tied, dist, strict=True) if dt == dmin)
            d = float(dmin)
        return int(i), d

    def within(self, point: NDArray[np.floating], radius: float) -> NDArray[np.int64]:
        """Sorted ids of the nodes at most `radius` m from `point` (boundary included)."""
        p = np.asarray(point, dtype=np.float64)[:3]
        ids = np.asarray(self.tree.query_ball_point(p, float(radius)), dtype=np.int64)
        return np.sort(ids)

    def local_candidates(
        self, prior_T_map_camera: NDArray[np.floating], desc: NDArray[np.float32], vpr: NDArray[np.float32],
        T_map_camera: NDArray[np.floating], neighbours: list[list[int]], radius_m: float, trigger_m: float,
        max_view_angle_deg: float, max_candidates: int,
    ) -> list[tuple[int, float]]:
        """LL candidates for a prior pose, best first: (node, VPR similarity).

        The rule of `VisualLocalizer.local_candidates`: none if the nearest node is farther
        than `trigger_m`; else the nearest node, its covisible `neighbours` and every node
        within `radius_m`, keeping those within max(radius_m, distance to the nearest node)
        whose optical axis is within `max_view_angle_deg` of the prior's; ranked by
        similarity of `vpr` (N, D) rows to `desc` (D,), ties by node id; the first
        `max_candidates`, then the nearest kept node where they leave it out.
        `T_map_camera` (N, 4, 4) are the node poses of this index."""
        prior = np.asarray(prior_T_map_camera, dtype=np.float64)
        p = prior[:3, 3]
        nearest, d_near = self.nearest(p)
        if d_near > trigger_m:
            return []
        cand = self.within(p, radius_m)
        extra = np.asarray([nearest, *neighbours[nearest]], dtype=np.int64)
        cand = np.union1d(cand, extra)
        d = np.linalg.norm(self.positions[cand] - p, axis=1)
        cos_max = np.cos(np.radians(max_view_angle_deg))
        view = np.asarray(T_map_camera, dtype=np.float64)[cand, :3, 2] @ prior[:3, 2]
        kept = (d <= max(radius_m, d_near)) & (view >= cos_max)
        keep = cand[kept]
        if len(keep) == 0:
            return []
        sims = vpr[keep] @ np.asarray(desc, dtype=np.float32)
        ranked = sorted(zip(keep.tolist(), sims.tolist(), strict=True), key=lambda x: (-x[1], x[0]))
        top = ranked[:max_candidates]
        # The nearest kept node is always tried, last where VPR ranks it lower: along a repeating
        # texture place descriptors rank the neighbours alike, and the nearest is the one a good prior verifies.
        i = int(np.argmin(d[kept]))
        if all(n != int(keep[i]) for n, _ in top):
            top.append((int(keep[i]), float(sims[i])))
        return top


def neighbour_lists(edges: NDArray[np.integer], weights: NDArray[np.floating], n: int) -> list[list[int]]:
    """Neighbours of each of `n` nodes in an undirected graph, strongest edge first.

    edges: (E, 2) node ids; weights: (E,). Ties in weight are ordered by neighbour id."""
    e = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    w = np.asarray(weights, dtype=np.float64)
    src = np.concatenate([e[:, 0], e[:, 1]])
    dst = np.concatenate([e[:, 1], e[:, 0]])
    ww = np.concatenate([w, w])
    order = np.lexsort((dst, -ww, src))
    src, dst = src[order], dst[order]
    bounds = np.searchsorted(src, np.arange(n + 1))
    flat = dst.tolist()
    return [flat[bounds[i]:bounds[i + 1]] for i in range(n)]


def connectivity_matrix(edges: NDArray[np.integer], metres: NDArray[np.floating], n: int) -> sp.csr_matrix:
    """(n, n) symmetric CSR matrix of edge lengths (m); the shortest of duplicate edges."""
    e = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    w = np.maximum(np.asarray(metres, dtype=np.float64), ZERO_EDGE_M)
    rows = np.concatenate([e[:, 0], e[:, 1]])
    cols = np.concatenate([e[:, 1], e[:, 0]])
    ww = np.concatenate([w, w])
    if len(rows):
        # keep the shortest of duplicate (row, col) pairs: sort by pair then length, take firsts
        order = np.lexsort((ww, cols, rows))
        rows, cols, ww = rows[order], cols[order], ww[order]
        first = np.ones(len(rows), dtype=bool)
        first[1:] = (rows[1:] != rows[:-1]) | (cols[1:] != cols[:-1])
        rows, cols, ww = rows[first], cols[first], ww[first]
    return sp.csr_matrix((ww, (rows, cols)), shape=(n, n))
