"""Node index (KD-tree), neighbour lists and the connectivity matrix against brute force."""

from __future__ import annotations

import heapq

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from litevloc.pipelines.topomap.node_index import NodeIndex, connectivity_matrix, neighbour_lists


# type: ignore[no-untyped-def]
def brute_local_candidates(pos, T, vpr, neighbours, prior, desc, radius, trigger, angle, k):
    """`VisualLocalizer.local_candidates` as written on main (linear scan)."""
    d = np.linalg.norm(pos - prior[:3, 3], axis=1)
    nearest = int(np.argmin(d))
    if d[nearest] > trigger:
        return []
    cos_max = np.cos(np.radians(angle))
    cand = {nearest} | set(neighbours[nearest])
    cand |= {int(i) for i in np.nonzero(d <= radius)[0]}
    keep = [i for i in cand if d[i] <= max(radius, d[nearest]) and float(T[i][:3, 2] @ prior[:3, 2]) >= cos_max]
    if not keep:
        return []
    sims = vpr[keep] @ desc
    top = sorted(zip(keep, sims.tolist(), strict=True), key=lambda x: (-x[1], x[0]))[:k]
    near = min(keep, key=lambda i: (d[i], i))  # the nearest kept node is always tried
    return top if any(n == near for n, _ in top) else [*top, (near, float(vpr[near] @ desc))]


def test_the_nearest_node_is_tried_where_place_descriptors_rank_it_out() -> None:
    """A corridor of 6 nodes 0.6 m apart looking the same way; the descriptors (as along a
    repeating texture) rank the farther ones first: the nearest comes last, after the top 3."""
    pos = np.array([[0.6 * i, 0.0, 0.0] for i in range(6)])
    T = np.tile(np.eye(4), (6, 1, 1))
    T[:, :3, 3] = pos
    vpr = np.eye(6, dtype=np.float32)
    desc = np.array([0.1, 0.2, 0.9, 0.8, 0.7, 0.6], dtype=np.float32)  # node 0 least alike
    idx = NodeIndex(pos)
    prior = np.eye(4)
    prior[0, 3] = 0.05  # at node 0
    got = idx.local_candidates(prior, desc, vpr, T, [[] for _ in range(6)], 3.0, 5.0, 90.0, 3)
    assert [n for n, _ in got] == [2, 3, 4, 0]
    prior[0, 3] = 1.8  # at node 3, already among the top 3: nothing added
    got = idx.local_candidates(prior, desc, vpr, T, [[] for _ in range(6)], 3.0, 5.0, 90.0, 3)
    assert [n for n, _ in got] == [2, 3, 4]


def random_map(n: int, rng: np.random.Generator, extent: float = 30.0):  # type: ignore[no-untyped-def]
    pos = rng.uniform(0, extent, (n, 3)) * [1, 1, 0.05]
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, :3] = Rotation.random(n, random_state=int(rng.integers(1 << 30))).as_matrix()
    T[:, :3, 3] = pos
    vpr = rng.normal(size=(n, 16)).astype(np.float32)
    vpr /= np.linalg.norm(vpr, axis=1, keepdims=True)
    e = rng.integers(0, n, (3 * n, 2))
    e = np.unique(np.sort(e[e[:, 0] != e[:, 1]], axis=1), axis=0)
    w = rng.choice([0.25, 0.5, 1.0], len(e)).astype(np.float32)  # repeated weights: ties by id
    return pos, T, vpr, e, w


def test_nearest_and_within_match_brute_force_including_ties() -> None:
    rng = np.random.default_rng(0)
    pos = rng.uniform(0, 10, (500, 3))
    pos[100] = pos[7]  # exact duplicates: the lowest id wins, as argmin
    pos[300] = pos[7]
    idx = NodeIndex(pos)
    for q in [*rng.uniform(-2, 12, (300, 3)), pos[7], pos[300]]:
        d = np.linalg.norm(pos - q, axis=1)
        i, di = idx.nearest(q)
        assert i == int(np.argmin(d)) and di == pytest.approx(float(d.min()))
        for r in (0.0, 0.5, 2.0):
            assert idx.within(q, r).tolist() == np.flatnonzero(d <= r).tolist()
    grid = NodeIndex(np.array([[0.0, 0, 0], [2, 0, 0], [1, 1, 0], [1, -1, 0]]))
    assert grid.nearest(np.array([1.0, 0, 0]))[0] == 0  # four nodes at 1 m: the lowest id


def test_index_rejects_bad_positions() -> None:
    with pytest.raises(ValueError, match="positions"):
        NodeIndex(np.zeros((0, 3)))
    with pytest.raises(ValueError, match="finite"):
        NodeIndex(np.array([[0.0, np.nan, 0]]))


def test_neighbour_lists_match_per_node_scan() -> None:
    rng = np.random.default_rng(1)
    _, _, _, e, w = random_map(200, rng)
    lists = neighbour_lists(e, w, 200)
    for node in range(200):
        ref = [(int(j), float(c)) for (i, j), c in zip(e, w, strict=True) if i == node]
        ref += [(int(i), float(c)) for (i, j), c in zip(e, w, strict=True) if j == node]
        assert lists[node] == [n for n, _ in sorted(ref, key=lambda x: (-x[1], x[0]))]
    assert neighbour_lists(np.zeros((0, 2), np.int64), np.zeros(0), 3) == [[], [], []]


@pytest.mark.parametrize("seed", [2, 3, 4])
def test_local_candidates_match_the_localizer_rule(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n = 400
    pos, T, vpr, e, w = random_map(n, rng)
    neighbours = neighbour_lists(e, w, n)
    idx = NodeIndex(pos)
    checked = 0
    for _ in range(300):
        P = np.eye(4)
        P[:3, :3] = Rotation.random(random_state=int(rng.integers(1 << 30))).as_matrix()
        P[:3, 3] = rng.uniform(-10, 40, 3) * [1, 1, 0.05]  # some priors far outside the map
        desc = rng.normal(size=16).astype(np.float32)
        for radius, trigger, angle, k in ((3.0, 7.5, 90.0, 3), (1.0, 2.0, 180.0, 10), (5.0, 5.0, 45.0, 5)):
            got = idx.local_candidates(P, desc, vpr, T, neighbours, radius, trigger, angle, k)
            ref = brute_local_candidates(pos, T, vpr, neighbours, P, desc, radius, trigger, angle, k)
            assert [c for c, _ in got] == [c for c, _ in ref]
            assert np.allclose([s for _, s in got], [s for _, s in ref], atol=1e-6)
            checked += bool(ref)
    assert checked > 300  # most queries have candidates (the far ones have none)


def heap_dijkstra(n: int, e: np.ndarray, w: np.ndarray, s: int) -> np.ndarray:
    adj: list[list[tuple[int, float]]] = [[] for _ in range(n)]
    for (i, j), c in zip(e, w, strict=True):
        adj[int(i)].append((int(j), float(c)))
        adj[int(j)].append((int(i), float(c)))
    dist = np.full(n, np.inf)
    dist[s] = 0
    h = [(0.0, s)]
    while h:
        d, u = heapq.heappop(h)
        if d > dist[u]:
            continue
        for v, c in adj[u]:
            if d + c < dist[v]:
                dist[v] = d + c
                heapq.heappush(h, (d + c, v))
    return dist


def test_connectivity_matrix_keeps_shortest_duplicate_and_zero_edges() -> None:
    from scipy.sparse.csgraph import dijkstra

    e = np.array([[0, 1], [0, 1], [1, 2], [2, 3]])
    w = np.array([5.0, 2.0, 0.0, 1.0])
    G = connectivity_matrix(e, w, 5)
    assert G[0, 1] == 2.0 and G[1, 0] == 2.0 and G[1, 2] > 0  # zero length kept as an edge
    d = dijkstra(G, indices=0)
    assert d[3] == pytest.approx(3.0) and np.isinf(d[4])
    rng = np.random.default_rng(5)
    _, _, _, e, w = random_map(300, rng)
    assert np.allclose(dijkstra(connectivity_matrix(e, w, 300), indices=0), heap_dijkstra(300, e, w, 0))


def test_local_candidates_equal_the_localizer_on_a_topomap() -> None:
    """Against `VisualLocalizer.local_candidates` itself (the code the index replaces)."""
    from litevloc.base.params.localization import LocalizationParams, SecondLookParams
    from litevloc.pipelines.localization.vloc import VisualLocalizer
    from litevloc.pipelines.topomap.types import NodeFeatures, OccupancyGrid, TopoMap

    rng = np.random.default_rng(6)
    n = 300
    _pos, T, vpr, e, w = random_map(n, rng, extent=20.0)
    f = NodeFeatures(np.zeros((0, 2), np.float32), np.zeros((0, 8), np.float32), np.zeros(0, np.float32), (64, 48))
    m = TopoMap(
        T_map_camera=T, K=np.tile(np.eye(3), (n, 1, 1)), image_size=np.tile([64, 48], (n, 1)).astype(np.int32),
        t_ns=np.arange(n, dtype=np.int64), frame_index=np.arange(n, dtype=np.int64), vpr=vpr, features=[f] * n,
        images_jpeg=[b""] * n, covis_edges=e, covis_inliers=np.full(len(e), 50, np.int32),
        covis_weight=w, conn_edges=np.zeros((0, 2), np.int64), conn_metres=np.zeros(0, np.float32),
        grid=OccupancyGrid(np.zeros((0, 0), np.uint8), np.zeros(2), 0.1, np.array([0.0, 0, 1]),
                           np.array([[1.0, 0, 0], [0, 1, 0]])),
    )
    p = LocalizationParams(second_look=SecondLookParams(candidates=0))  # its candidates only, no look
    loc = VisualLocalizer(m, p, lambda im: f, lambda im: np.zeros(16, np.float32),
                          lambda a, b: (np.zeros(0, np.int64), np.zeros(0, np.int64)))
    for _ in range(200):
        P = np.eye(4)
        P[:3, :3] = Rotation.random(random_state=int(rng.integers(1 << 30))).as_matrix()
        P[:3, 3] = rng.uniform(-10, 30, 3) * [1, 1, 0.05]
        desc = rng.normal(size=16).astype(np.float32)
        ls = p.local_search
        got = m.node_index.local_candidates(P, desc, m.vpr, m.T_map_camera, m.covisibility_lists,
                                            ls.candidate_radius_m, ls.trigger_distance_m, ls.max_view_angle_deg,
                                            ls.max_candidates)
        ref = loc.local_search.candidates(loc.params, P, desc)
        assert [c for c, _ in got] == [c for c, _ in ref]
    # the covisibility lists are the localizer's neighbour order (strongest first, ties by id)
    assert m.covisibility_lists == [[k for k, _ in sorted(m.covisible_neighbours(i), key=lambda x: (-x[1], x[0]))]
                                    for i in range(n)]
