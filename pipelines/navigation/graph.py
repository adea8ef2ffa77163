"""The connectivity graph and the occupancy grid as the tracker and the goal placement use them.

* `shortest_path`: Dijkstra on the connectivity graph (edge weights in metres) with
  `scipy.sparse.csgraph.dijkstra` on the map's CSR matrix (built once per map); ~1 ms at
  10,000 nodes where the former pure-Python heap took tens (`bench/scale.py`).
* `against_view_graph`: the graph the tracker plans on: an edge driven against both of its
  keyframes' viewing directions costs `tracker.against_view_cost` times its length.
* `segment_clear` / `segment_distance`: a straight line on the map's occupancy grid, and a
  point's distance from a segment.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray
from scipy.sparse.csgraph import dijkstra

from litevloc.base.errors import LiteVLocError
from litevloc.pipelines.topomap.node_index import ZERO_EDGE_M
from litevloc.pipelines.topomap.types import TopoMap


class NavigationError(LiteVLocError, ValueError):
    """No path, bad node ids, or an unusable goal."""


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
