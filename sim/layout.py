"""Floor plans: a label grid of rooms and corridors, doors between them, and the wall faces.

Generation works on a label grid of `cell`-metre squares (0 = solid, k > 0 = region k: a
room or a corridor). Walls are the axis-aligned boundaries between different labels; doors
are gaps cut into the boundary between two regions (a random spanning tree of the region
graph, so every region is reachable, plus extra doors).
"""

from __future__ import annotations

import heapq
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from litevloc.sim.elements import Face, Region
from litevloc.sim.spec import WorldSpec

Door = tuple[int, int, float, float, float, float]  # region a, region b, x0, y0, x1, y1 (m)


@dataclass
class FloorPlan:
    """Regions, doors and wall faces of a building (before furniture)."""

    labels: NDArray[np.int32]  # (H, W) region label per cell, 0 = solid; padded by one solid cell
    regions: dict[int, Region]
    doors: list[Door] = field(default_factory=list)
    door_edges: set[tuple[int, int, int]] = field(default_factory=set)
    faces: list[Face] = field(default_factory=list)


def make_floor_plan(spec: WorldSpec, rng: np.random.Generator) -> FloorPlan:
    """The floor plan of `spec`: layout (room sizes jittered with the seed's own stream), then
    doors and walls drawn from `rng` (the building's main stream)."""
    jitter = np.random.default_rng([spec.seed, 1])
    labels, regions = _layout(spec, jitter)
    plan = FloorPlan(labels, regions)
    _make_doors(plan, spec, rng)
    _make_walls(plan, spec)
    return plan


def _cells(spec: WorldSpec, metres: float) -> int:
    return max(1, round(metres / spec.cell))


def _sizes(spec: WorldSpec, n: int, metres: float, rng: np.random.Generator) -> list[int]:
    """n room extents in cells: `metres` times a factor in [1 -+ room_size_jitter]."""
    j = spec.room_size_jitter
    if j == 0:
        return [_cells(spec, metres)] * n
    return [_cells(spec, metres * f) for f in rng.uniform(1 - j, 1 + j, n)]


def _layout(spec: WorldSpec, jitter: np.random.Generator) -> tuple[NDArray[np.int32], dict[int, Region]]:
    s = spec
    cw = _cells(s, s.corridor_width) if s.corridor_width > 0 else 0
    regions: dict[int, Region] = {}
    if s.layout == "grid":
        widths = _sizes(s, s.cols, s.room_size[0], jitter)
        depths = _sizes(s, s.rows, s.room_size[1], jitter)
        xs = np.concatenate([[0], np.cumsum(widths)]).astype(int)
        ys = np.concatenate([[0], np.cumsum(np.array(depths) + cw)]).astype(int)
        h = int(ys[-1] - cw)
        w = int(xs[-1] + (cw if cw and s.rows > 1 else 0))
        lab = np.zeros((h, w), np.int32)
        label = 1
        for r in range(s.rows):
            for c in range(s.cols):
                lab[ys[r] : ys[r] + depths[r], xs[c] : xs[c + 1]] = label
                regions[label] = Region(label, f"room_{label - 1:02d}", "room")
                label += 1
        if cw and s.rows > 1:
            for r in range(s.rows - 1):
                y0 = ys[r] + depths[r]
                lab[y0 : y0 + cw, :] = label
            lab[:, xs[-1] :] = label
            regions[label] = Region(label, "corridor", "corridor")
    else:
        W, H = _cells(s, s.loop_size[0]), _cells(s, s.loop_size[1])
        lab = np.zeros((H, W), np.int32)
        lab[:, :] = 1
        regions[1] = Region(1, "corridor", "corridor")
        inner_w, inner_h = W - 2 * cw, H - 2 * cw
        xl = np.linspace(cw, cw + inner_w, s.cols + 1).round().astype(int)
        yl = np.linspace(cw, cw + inner_h, s.rows + 1).round().astype(int)
        label = 2
        for r in range(s.rows):
            for c in range(s.cols):
                lab[yl[r] : yl[r + 1], xl[c] : xl[c + 1]] = label
                regions[label] = Region(label, f"room_{label - 2:02d}", "room")
                label += 1
    # pad with one solid cell on every side so the outside is label 0
    lab = np.pad(lab, 1)
    cs = s.cell
    for k, reg in regions.items():
        ys_, xs_ = np.nonzero(lab == k)
        reg.cells = len(xs_)
        reg.bbox = (xs_.min() * cs, ys_.min() * cs, (xs_.max() + 1) * cs, (ys_.max() + 1) * cs)
    return lab, regions


def _boundary_runs(lab: NDArray[np.int32], a: int, b: int) -> list[list[tuple[int, int, int]]]:
    """Straight runs of grid edges between regions a and b.

    Edge (0, i, j): horizontal edge at grid line y = i between cells (i-1, j), (i, j).
    Edge (1, i, j): vertical edge at grid line x = j between cells (i, j-1), (i, j).
    """
    runs: list[list[tuple[int, int, int]]] = []
    up, down = lab[:-1, :], lab[1:, :]
    m = ((up == a) & (down == b)) | ((up == b) & (down == a))
    for i, row in enumerate(m):
        js = np.nonzero(row)[0]
        runs += [
            [(0, i + 1, int(j)) for j in g]
            for g in np.split(js, np.nonzero(np.diff(js) > 1)[0] + 1)
            if len(g)
        ]
    le, ri = lab[:, :-1], lab[:, 1:]
    m = ((le == a) & (ri == b)) | ((le == b) & (ri == a))
    for j, col in enumerate(m.T):
        is_ = np.nonzero(col)[0]
        runs += [
            [(1, int(i), j + 1) for i in g]
            for g in np.split(is_, np.nonzero(np.diff(is_) > 1)[0] + 1)
            if len(g)
        ]
    return runs


def _make_doors(plan: FloorPlan, spec: WorldSpec, rng: np.random.Generator) -> None:
    lab, regions = plan.labels, plan.regions
    pairs: set[tuple[int, int]] = set()
    for A, B in ((lab[:-1, :], lab[1:, :]), (lab[:, :-1], lab[:, 1:])):
        m = (A != B) & (A > 0) & (B > 0)
        for a, b in zip(A[m].tolist(), B[m].tolist(), strict=True):
            pairs.add((min(a, b), max(a, b)))
    pairs_sorted = sorted(pairs)
    for a, b in pairs_sorted:
        regions[a].neighbours.append(b)
        regions[b].neighbours.append(a)
    # random spanning tree (Prim with random weights; corridor links cheaper)
    weights = {}
    for a, b in pairs_sorted:
        corr = regions[a].kind == "corridor" or regions[b].kind == "corridor"
        weights[(a, b)] = rng.random() * (0.3 if corr else 1.0)
    chosen: set[tuple[int, int]] = set()
    start = min(regions)
    seen = {start}
    heap = [
        (weights[(min(start, n), max(start, n))], min(start, n), max(start, n))
        for n in regions[start].neighbours
    ]
    heapq.heapify(heap)
    while heap:
        _, a, b = heapq.heappop(heap)
        new = b if a in seen else a
        if new in seen:
            continue
        seen.add(new)
        chosen.add((a, b))
        for n in regions[new].neighbours:
            if n not in seen:
                heapq.heappush(heap, (weights[(min(new, n), max(new, n))], min(new, n), max(new, n)))
    for a, b in pairs_sorted:
        corr = regions[a].kind == "corridor" or regions[b].kind == "corridor"
        p = 0.85 if corr else spec.extra_door_prob
        if (a, b) in chosen or rng.random() < p:
            _cut_door(plan, spec, rng, a, b)


def _cut_door(plan: FloorPlan, spec: WorldSpec, rng: np.random.Generator, a: int, b: int) -> None:
    nd = _cells(spec, spec.door_width)
    margin = _cells(spec, 0.5)
    runs = [r for r in _boundary_runs(plan.labels, a, b) if len(r) >= nd + 2 * margin]
    if not runs:
        runs = [r for r in _boundary_runs(plan.labels, a, b) if len(r) >= nd]
        margin = 0
    if not runs:
        return
    run = max(runs, key=len)
    k0 = int(rng.integers(margin, len(run) - nd - margin + 1))
    edges = run[k0 : k0 + nd]
    plan.door_edges.update(edges)
    c = spec.cell
    o, i, j = edges[0]
    _o2, i2, j2 = edges[-1]
    if o == 0:
        plan.doors.append((a, b, j * c, i * c, (j2 + 1) * c, i * c))
    else:
        plan.doors.append((a, b, j * c, i * c, j * c, (i2 + 1) * c))


def _make_walls(plan: FloorPlan, spec: WorldSpec) -> None:
    lab, c, H = plan.labels, spec.cell, spec.wall_height
    # horizontal grid lines: y = i * c, between rows i-1 and i
    for i in range(1, lab.shape[0]):
        _merge_edges(plan, 0, i, lab[i - 1], lab[i], c, H)
    for j in range(1, lab.shape[1]):
        _merge_edges(plan, 1, j, lab[:, j - 1], lab[:, j], c, H)


def _merge_edges(
    plan: FloorPlan, o: int, line: int, la: NDArray[np.int32], lb: NDArray[np.int32], c: float, H: float
) -> None:
    n = len(la)
    k = 0
    door_edges = plan.door_edges
    while k < n:
        key = (o, line, k) if o == 0 else (o, k, line)
        if la[k] == lb[k] or key in door_edges:
            k += 1
            continue
        k1 = k
        while k1 + 1 < n and la[k1 + 1] == la[k] and lb[k1 + 1] == lb[k]:
            nxt = (o, line, k1 + 1) if o == 0 else (o, k1 + 1, line)
            if nxt in door_edges:
                break
            k1 += 1
        # o == 0: wall in a plane y = line*c (axis 1), spanning x; o == 1: plane x = c (axis 0)
        axis = 1 if o == 0 else 0
        lo, hi = k * c, (k1 + 1) * c
        a, b = int(la[k]), int(lb[k])
        if a > 0:
            plan.faces.append(Face(axis, line * c, lo, hi, -1, H, a, "wall"))
        if b > 0:
            plan.faces.append(Face(axis, line * c, lo, hi, +1, H, b, "wall"))
        k = k1 + 1
