"""Procedural indoor worlds: floor plans of rooms and corridors with doors and furniture.

A world is generated from a `WorldSpec` (loaded strictly from YAML in
`config/worlds/<name>.yaml`) and the spec's seed. Generation works on a label grid of
`cell`-metre squares (0 = solid, k > 0 = region k: a room or a corridor): walls are the
axis-aligned boundaries between different labels, doors are gaps cut into the boundary
between two regions (a random spanning tree of the region graph, so every region is
reachable, plus extra doors). Furniture is boxes standing against walls, away from doors.

World frame: z up, metres; the floor is z = 0 and the ceiling z = `wall_height`.

Geometry handed to the renderer:

* `faces`: vertical rectangles (one per side of each wall segment, four per box), each
  with an axis (0: the face lies in a plane x = c, 1: y = c), the plane coordinate `c`,
  the extent [lo, hi] along the other axis, an outward normal sign and a height.
* `boxes`: (N, 5) x0, y0, x1, y1, height.

Textures (see `litevloc.sim.textures`) are baked once per world into an atlas.
"""

from __future__ import annotations

import dataclasses
import heapq
import importlib.util
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Literal

import cv2
import numpy as np
from numpy.typing import NDArray

from litevloc.base.loader import ConfigError, from_mapping, load_yaml

if TYPE_CHECKING:
    from litevloc.sim.textures import BakedTextures


def _worlds_dir() -> Path:
    # the world files are data of the config package: locate it without importing it (hw never imports config)
    spec = importlib.util.find_spec("litevloc.config")
    if spec is None or not spec.submodule_search_locations:
        raise ConfigError("the litevloc.config package (with config/worlds/*.yaml) is not installed")
    return Path(next(iter(spec.submodule_search_locations))).resolve() / "worlds"


@dataclass(frozen=True)
class WorldSpec:
    """Description of a procedural world (all lengths metres).

    layout "grid": `rows` x `cols` rooms of `room_size` (x, y); with `corridor_width` > 0
    a corridor runs between consecutive rows of rooms, joined by one along the east side.
    layout "loop": a ring corridor of outer size `loop_size` and width `corridor_width`
    around a block divided into `rows` x `cols` rooms (a long loop for drift tests).
    """

    name: str
    seed: int = 0
    layout: Literal["grid", "loop"] = "grid"
    rows: int = 2
    cols: int = 2
    room_size: tuple[float, float] = (5.0, 4.0)
    corridor_width: float = 0.0
    loop_size: tuple[float, float] = (60.0, 40.0)
    wall_height: float = 2.6
    cell: float = 0.25
    door_width: float = 1.0
    extra_door_prob: float = 0.3
    furniture_per_room: tuple[int, int] = (2, 5)
    posters_per_room: tuple[int, int] = (1, 3)
    texture_poor_fraction: float = 0.25
    repetitive_fraction: float = 0.25
    texels_per_m: float = 64.0
    # A changed version of the same world (for map update tests): with change_seed >= 0, after
    # generation a `change_fraction` of the posters get another picture and of the furniture
    # (pillars excepted) slides 0.5-1.5 m along its wall where the room allows; < 0: as generated.
    change_seed: int = -1
    change_fraction: float = 0.5

    def __post_init__(self) -> None:
        if not self.name:
            raise ValueError("name must not be empty")
        if self.rows < 1 or self.cols < 1 or self.rows * self.cols > 400:
            raise ValueError(
                f"rows, cols must be >= 1 with at most 400 rooms, got {self.rows}x{self.cols}"
            )
        if not (0.05 <= self.cell <= 1.0):
            raise ValueError(f"cell must be in [0.05, 1] m, got {self.cell}")
        if min(self.room_size) < 2.0 or max(self.room_size) > 50:
            raise ValueError(f"room_size must be in [2, 50] m, got {self.room_size}")
        if self.corridor_width != 0 and not (1.0 <= self.corridor_width <= 10):
            raise ValueError(f"corridor_width must be 0 or in [1, 10] m, got {self.corridor_width}")
        if self.layout == "loop":
            if self.corridor_width == 0:
                raise ValueError("layout 'loop' needs corridor_width > 0")
            if min(self.loop_size) < 2 * self.corridor_width + 4 or max(self.loop_size) > 200:
                raise ValueError(
                    f"loop_size {self.loop_size} too small for the corridor, or > 200 m"
                )
        if not (1.5 <= self.wall_height <= 6):
            raise ValueError(f"wall_height must be in [1.5, 6] m, got {self.wall_height}")
        if not (0.6 <= self.door_width <= 3):
            raise ValueError(f"door_width must be in [0.6, 3] m, got {self.door_width}")
        for name in ("extra_door_prob", "texture_poor_fraction", "repetitive_fraction", "change_fraction"):
            v = getattr(self, name)
            if not (0 <= v <= 1):
                raise ValueError(f"{name} must be in [0, 1], got {v}")
        for name in ("furniture_per_room", "posters_per_room"):
            lo, hi = getattr(self, name)
            if lo < 0 or hi < lo or hi > 20:
                raise ValueError(
                    f"{name} must be [min, max] with 0 <= min <= max <= 20, got {(lo, hi)}"
                )
        if not (16 <= self.texels_per_m <= 256):
            raise ValueError(f"texels_per_m must be in [16, 256], got {self.texels_per_m}")


def world_names() -> list[str]:
    """Names of the shipped worlds (file stems in config/worlds)."""
    return sorted(p.stem for p in _worlds_dir().glob("*.yaml"))


def resolve_world_path(name_or_path: str | Path) -> Path:
    """A shipped world name ("office") or a path to a YAML file -> existing path."""
    p = Path(name_or_path)
    if p.suffix in (".yaml", ".yml"):
        if p.is_file():
            return p
        shipped = _worlds_dir() / p.name
        if p.parent == Path(".") and shipped.is_file():
            return shipped
        raise ConfigError(f"world file not found: {p}")
    shipped = _worlds_dir() / f"{name_or_path}.yaml"
    if shipped.is_file():
        return shipped
    raise ConfigError(
        f"unknown world {str(name_or_path)!r}: not a file, and shipped worlds are {world_names()}"
    )


def load_world_spec(name_or_path: str | Path) -> WorldSpec:
    path = resolve_world_path(name_or_path)
    return from_mapping(WorldSpec, load_yaml(path), str(path))


def load_world(name_or_path: str | Path, seed: int | None = None) -> World:
    """Load a world by shipped name or YAML path; `seed` overrides the spec's seed."""
    spec = load_world_spec(name_or_path)
    if seed is not None:
        spec = WorldSpec(**{**spec.__dict__, "seed": int(seed)})
    return World(spec)


@dataclass(frozen=True)
class Face:
    """A vertical textured rectangle: plane `axis` (0: x = c, 1: y = c), extent [lo, hi]."""

    axis: int
    c: float
    lo: float
    hi: float
    normal: int  # +1 / -1: the side of the plane the face is seen from
    height: float
    region: int  # region the face looks into (0 = outside / furniture)
    kind: Literal["wall", "box"]
    box: int = -1  # index into World.boxes for box faces


@dataclass(frozen=True)
class Poster:
    """A picture on a wall face: face index, s (m along the face), z (m), size, image id."""

    face: int
    s0: float
    z0: float
    width: float
    height: float
    image: str


@dataclass
class Region:
    label: int
    name: str
    kind: Literal["room", "corridor"]
    material: str = "painted"
    cells: int = 0
    bbox: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)  # x0, y0, x1, y1
    neighbours: list[int] = field(default_factory=list)


class World:
    """Geometry and appearance of one generated world (see module docstring)."""

    def __init__(self, spec: WorldSpec) -> None:
        self.spec = spec
        self.rng = np.random.default_rng(spec.seed)
        self.wall_height = spec.wall_height
        self.labels, self.regions = self._layout()
        self.doors: list[tuple[int, int, float, float, float, float]] = []  # a, b, x0, y0, x1, y1
        self._door_edges: set[tuple[int, int, int]] = set()
        self._make_doors()
        self.faces: list[Face] = []
        self._make_walls()
        self.boxes = np.zeros((0, 5))
        self._make_furniture()
        self.posters: list[Poster] = []
        self._assign_materials()
        self.changes: dict[str, int] = {"posters": 0, "furniture": 0}
        if spec.change_seed >= 0:
            self._apply_changes(np.random.default_rng(spec.change_seed), spec.change_fraction)
        self.goal_places: dict[str, NDArray[np.float64]] = self._make_goals()
        # textures baked on first render (`litevloc.sim.render.baked_textures`), cached here
        self._baked: BakedTextures | None = None

    # ------------------------------------------------------------------ layout
    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """x0, y0, x1, y1 of the label grid (metres)."""
        c = self.spec.cell
        return 0.0, 0.0, self.labels.shape[1] * c, self.labels.shape[0] * c

    def _cells(self, metres: float) -> int:
        return max(1, round(metres / self.spec.cell))

    def _layout(self) -> tuple[NDArray[np.int32], dict[int, Region]]:
        s = self.spec
        rw, rh = self._cells(s.room_size[0]), self._cells(s.room_size[1])
        cw = self._cells(s.corridor_width) if s.corridor_width > 0 else 0
        regions: dict[int, Region] = {}
        if s.layout == "grid":
            h = s.rows * rh + (s.rows - 1) * cw
            w = s.cols * rw + (cw if cw and s.rows > 1 else 0)
            lab = np.zeros((h, w), np.int32)
            label = 1
            for r in range(s.rows):
                y0 = r * (rh + cw)
                for c in range(s.cols):
                    lab[y0 : y0 + rh, c * rw : (c + 1) * rw] = label
                    regions[label] = Region(label, f"room_{label - 1:02d}", "room")
                    label += 1
            if cw and s.rows > 1:
                for r in range(s.rows - 1):
                    y0 = r * (rh + cw) + rh
                    lab[y0 : y0 + cw, :] = label
                lab[:, s.cols * rw :] = label
                regions[label] = Region(label, "corridor", "corridor")
        else:
            W, H = self._cells(s.loop_size[0]), self._cells(s.loop_size[1])
            lab = np.zeros((H, W), np.int32)
            lab[:, :] = 1
            regions[1] = Region(1, "corridor", "corridor")
            inner_w, inner_h = W - 2 * cw, H - 2 * cw
            xs = np.linspace(cw, cw + inner_w, s.cols + 1).round().astype(int)
            ys = np.linspace(cw, cw + inner_h, s.rows + 1).round().astype(int)
            label = 2
            for r in range(s.rows):
                for c in range(s.cols):
                    lab[ys[r] : ys[r + 1], xs[c] : xs[c + 1]] = label
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

    def _boundary_runs(self, a: int, b: int) -> list[list[tuple[int, int, int]]]:
        """Straight runs of grid edges between regions a and b.

        Edge (0, i, j): horizontal edge at grid line y = i between cells (i-1, j), (i, j).
        Edge (1, i, j): vertical edge at grid line x = j between cells (i, j-1), (i, j).
        """
        lab = self.labels
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

    def _make_doors(self) -> None:
        lab = self.labels
        pairs: set[tuple[int, int]] = set()
        for A, B in ((lab[:-1, :], lab[1:, :]), (lab[:, :-1], lab[:, 1:])):
            m = (A != B) & (A > 0) & (B > 0)
            for a, b in zip(A[m].tolist(), B[m].tolist(), strict=True):
                pairs.add((min(a, b), max(a, b)))
        pairs_sorted = sorted(pairs)
        for a, b in pairs_sorted:
            self.regions[a].neighbours.append(b)
            self.regions[b].neighbours.append(a)
        # random spanning tree (Prim with random weights; corridor links cheaper)
        weights = {}
        for a, b in pairs_sorted:
            corr = self.regions[a].kind == "corridor" or self.regions[b].kind == "corridor"
            weights[(a, b)] = self.rng.random() * (0.3 if corr else 1.0)
        chosen: set[tuple[int, int]] = set()
        start = min(self.regions)
        seen = {start}
        heap = [
            (weights[(min(start, n), max(start, n))], min(start, n), max(start, n))
            for n in self.regions[start].neighbours
        ]
        heapq.heapify(heap)
        while heap:
            _, a, b = heapq.heappop(heap)
            new = b if a in seen else a
            if new in seen:
                continue
            seen.add(new)
            chosen.add((a, b))
            for n in self.regions[new].neighbours:
                if n not in seen:
                    heapq.heappush(
                        heap, (weights[(min(new, n), max(new, n))], min(new, n), max(new, n))
                    )
        for a, b in pairs_sorted:
            corr = self.regions[a].kind == "corridor" or self.regions[b].kind == "corridor"
            p = 0.85 if corr else self.spec.extra_door_prob
            if (a, b) in chosen or self.rng.random() < p:
                self._cut_door(a, b)

    def _cut_door(self, a: int, b: int) -> None:
        nd = self._cells(self.spec.door_width)
        margin = self._cells(0.5)
        runs = [r for r in self._boundary_runs(a, b) if len(r) >= nd + 2 * margin]
        if not runs:
            runs = [r for r in self._boundary_runs(a, b) if len(r) >= nd]
            margin = 0
        if not runs:
            return
        run = max(runs, key=len)
        k0 = int(self.rng.integers(margin, len(run) - nd - margin + 1))
        edges = run[k0 : k0 + nd]
        self._door_edges.update(edges)
        c = self.spec.cell
        o, i, j = edges[0]
        _o2, i2, j2 = edges[-1]
        if o == 0:
            self.doors.append((a, b, j * c, i * c, (j2 + 1) * c, i * c))
        else:
            self.doors.append((a, b, j * c, i * c, j * c, (i2 + 1) * c))

    def _make_walls(self) -> None:
        lab, c, H = self.labels, self.spec.cell, self.wall_height
        # horizontal grid lines: y = i * c, between rows i-1 and i
        for i in range(1, lab.shape[0]):
            la, lb = lab[i - 1], lab[i]
            self._merge_edges(0, i, la, lb, c, H)
        for j in range(1, lab.shape[1]):
            la, lb = lab[:, j - 1], lab[:, j]
            self._merge_edges(1, j, la, lb, c, H)

    def _merge_edges(
        self, o: int, line: int, la: NDArray[np.int32], lb: NDArray[np.int32], c: float, H: float
    ) -> None:
        n = len(la)
        k = 0
        while k < n:
            key = (o, line, k) if o == 0 else (o, k, line)
            if la[k] == lb[k] or key in self._door_edges:
                k += 1
                continue
            k1 = k
            while k1 + 1 < n and la[k1 + 1] == la[k] and lb[k1 + 1] == lb[k]:
                nxt = (o, line, k1 + 1) if o == 0 else (o, k1 + 1, line)
                if nxt in self._door_edges:
                    break
                k1 += 1
            # o == 0: wall in a plane y = line*c (axis 1), spanning x; o == 1: plane x = c (axis 0)
            axis = 1 if o == 0 else 0
            lo, hi = k * c, (k1 + 1) * c
            a, b = int(la[k]), int(lb[k])
            if a > 0:
                self.faces.append(Face(axis, line * c, lo, hi, -1, H, a, "wall"))
            if b > 0:
                self.faces.append(Face(axis, line * c, lo, hi, +1, H, b, "wall"))
            k = k1 + 1

    # --------------------------------------------------------------- furniture
    def _make_furniture(self) -> None:
        s = self.spec
        boxes: list[tuple[float, float, float, float, float]] = []
        door_pts = np.array([((d[2] + d[4]) / 2, (d[3] + d[5]) / 2) for d in self.doors]).reshape(
            -1, 2
        )
        kinds = [
            ("cabinet", (0.6, 1.4), (0.4, 0.6), (0.8, 1.1)),
            ("shelf", (0.8, 1.8), (0.3, 0.45), (1.6, 2.1)),
            ("desk", (1.0, 1.8), (0.6, 0.8), (0.72, 0.78)),
            ("pillar", (0.4, 0.6), (0.4, 0.6), (s.wall_height, s.wall_height)),
        ]
        for reg in self.regions.values():
            if reg.kind != "room":
                continue
            x0, y0, x1, y1 = reg.bbox
            n = int(self.rng.integers(s.furniture_per_room[0], s.furniture_per_room[1] + 1))
            for _ in range(n * 6):
                if n <= 0:
                    break
                kind, (la, lb), (da, db), (ha, hb) = kinds[
                    int(self.rng.choice(4, p=[0.35, 0.3, 0.3, 0.05]))
                ]
                length, depth, h = (
                    self.rng.uniform(la, lb),
                    self.rng.uniform(da, db),
                    self.rng.uniform(ha, hb),
                )
                side = int(self.rng.integers(4))
                gap = 0.05
                if side in (0, 1):  # against the west / east wall
                    if y1 - y0 < length + 1.0:
                        continue
                    by0 = self.rng.uniform(y0 + 0.3, y1 - 0.3 - length)
                    bx0 = x0 + gap if side == 0 else x1 - gap - depth
                    box = (bx0, by0, bx0 + depth, by0 + length, h)
                else:
                    if x1 - x0 < length + 1.0:
                        continue
                    bx0 = self.rng.uniform(x0 + 0.3, x1 - 0.3 - length)
                    by0 = y0 + gap if side == 2 else y1 - gap - depth
                    box = (bx0, by0, bx0 + length, by0 + depth, h)
                if kind == "pillar":
                    cx, cy = (
                        self.rng.uniform(x0 + 1.5, x1 - 1.5),
                        self.rng.uniform(y0 + 1.5, y1 - 1.5),
                    )
                    if x1 - x0 < 5 or y1 - y0 < 5:
                        continue
                    box = (
                        cx - depth / 2,
                        cy - length / 2 * 0.5,
                        cx + depth / 2,
                        cy + length / 2 * 0.5,
                        h,
                    )
                bx = np.array(box[:4])
                # keep doors clear (1.3 m) and boxes 0.9 m apart (passages stay open)
                if len(door_pts):
                    dx = np.maximum(np.maximum(bx[0] - door_pts[:, 0], door_pts[:, 0] - bx[2]), 0)
                    dy = np.maximum(np.maximum(bx[1] - door_pts[:, 1], door_pts[:, 1] - bx[3]), 0)
                    if np.any(np.hypot(dx, dy) < 1.3):
                        continue
                if any(
                    bx[0] < o[2] + 0.9
                    and o[0] < bx[2] + 0.9
                    and bx[1] < o[3] + 0.9
                    and o[1] < bx[3] + 0.9
                    for o in boxes
                ):
                    continue
                boxes.append(box)
                n -= 1
        self.boxes = np.array(boxes, dtype=np.float64).reshape(-1, 5)
        self._box_faces()
        self.box_kinds = [
            "pillar"
            if h >= s.wall_height - 1e-6
            else "desk"
            if h < 0.8
            else "shelf"
            if h > 1.5
            else "cabinet"
            for h in self.boxes[:, 4]
        ]

    def _box_faces(self) -> None:
        """(Re)create the four faces of every box (box faces follow all wall faces)."""
        self.faces = [f for f in self.faces if f.kind != "box"]
        for k, (bx0, by0, bx1, by1, h) in enumerate(self.boxes):
            self.faces.append(Face(0, bx0, by0, by1, -1, h, 0, "box", k))
            self.faces.append(Face(0, bx1, by0, by1, +1, h, 0, "box", k))
            self.faces.append(Face(1, by0, bx0, bx1, -1, h, 0, "box", k))
            self.faces.append(Face(1, by1, bx0, bx1, +1, h, 0, "box", k))

    def _apply_changes(self, rng: np.random.Generator, fraction: float) -> None:
        """Re-texture posters and slide furniture along its wall (see `WorldSpec.change_seed`)."""
        from litevloc.sim.textures import POSTER_IMAGES

        for i, p in enumerate(self.posters):
            if rng.random() < fraction:
                others = [img for img in POSTER_IMAGES if img != p.image]
                if others:
                    self.posters[i] = dataclasses.replace(p, image=str(rng.choice(others)))
                    self.changes["posters"] += 1
        door_pts = np.array([((d[2] + d[4]) / 2, (d[3] + d[5]) / 2) for d in self.doors]).reshape(-1, 2)
        boxes = self.boxes.copy()
        for k in range(len(boxes)):
            if self.box_kinds[k] == "pillar" or rng.random() >= fraction:
                continue
            bx0, by0, bx1, by1, _h = boxes[k]
            cx, cy = (bx0 + bx1) / 2, (by0 + by1) / 2
            label = self.region_at(np.array([cx, cy]))
            reg = self.regions.get(label)
            if reg is None:
                continue
            rx0, ry0, rx1, ry1 = reg.bbox
            along_x = (bx1 - bx0) >= (by1 - by0)  # slide along the box's long side (its wall)
            for _ in range(10):
                shift = rng.uniform(0.5, 1.5) * rng.choice([-1.0, 1.0])
                nb = boxes[k].copy()
                if along_x:
                    nb[[0, 2]] += shift
                else:
                    nb[[1, 3]] += shift
                if nb[0] < rx0 + 0.3 or nb[2] > rx1 - 0.3 or nb[1] < ry0 or nb[3] > ry1:
                    continue
                if len(door_pts):
                    dx = np.maximum(np.maximum(nb[0] - door_pts[:, 0], door_pts[:, 0] - nb[2]), 0)
                    dy = np.maximum(np.maximum(nb[1] - door_pts[:, 1], door_pts[:, 1] - nb[3]), 0)
                    if np.any(np.hypot(dx, dy) < 1.3):
                        continue
                if any(nb[0] < o[2] + 0.9 and o[0] < nb[2] + 0.9 and nb[1] < o[3] + 0.9 and o[1] < nb[3] + 0.9
                       for j, o in enumerate(boxes) if j != k):
                    continue
                boxes[k] = nb
                self.changes["furniture"] += 1
                break
        self.boxes = boxes
        self._box_faces()

    # --------------------------------------------------------------- materials
    def _assign_materials(self) -> None:
        s = self.spec
        rooms = [r for r in self.regions.values() if r.kind == "room"]
        order = self.rng.permutation(len(rooms))
        n_poor = round(s.texture_poor_fraction * len(rooms))
        n_rep = round(s.repetitive_fraction * len(rooms))
        for rank, idx in enumerate(order):
            r = rooms[int(idx)]
            if rank < n_poor:
                r.material = "painted"
            elif rank < n_poor + n_rep:
                r.material = "brick"
            else:
                r.material = str(self.rng.choice(["plaster", "wallpaper", "panel", "brick"]))
        for r in self.regions.values():
            if r.kind == "corridor":
                r.material = "painted"
        # posters: on wall faces of rooms (not texture-poor ones: at most one there)
        from litevloc.sim.textures import POSTER_IMAGES

        faces_by_region: dict[int, list[int]] = {}
        for i, f in enumerate(self.faces):
            if f.kind == "wall" and f.hi - f.lo >= 1.6:
                faces_by_region.setdefault(f.region, []).append(i)
        for r in self.regions.values():
            cand = faces_by_region.get(r.label, [])
            if not cand:
                continue
            lo_n, hi_n = s.posters_per_room
            n = int(self.rng.integers(lo_n, hi_n + 1))
            if r.material == "painted" and r.kind == "room":
                n = min(n, 1)
            if r.kind == "corridor":
                n = max(1, int(sum(self.faces[i].hi - self.faces[i].lo for i in cand) / 6.0))
            for _ in range(n):
                fi = int(self.rng.choice(cand))
                f = self.faces[fi]
                w = self.rng.uniform(0.6, min(1.4, f.hi - f.lo - 0.4))
                hgt = w * self.rng.uniform(0.6, 1.0)
                s0 = self.rng.uniform(0.2, f.hi - f.lo - w - 0.2)
                z0 = self.rng.uniform(0.9, max(0.95, min(2.0, self.wall_height - 0.2) - hgt))
                if any(
                    p.face == fi and p.s0 < s0 + w + 0.1 and s0 < p.s0 + p.width + 0.1
                    for p in self.posters
                ):
                    continue
                self.posters.append(Poster(fi, s0, z0, w, hgt, str(self.rng.choice(POSTER_IMAGES))))

    # ------------------------------------------------------------------- goals
    def _make_goals(self) -> dict[str, NDArray[np.float64]]:
        """One goal place per room: a free spot ~2.5 m in front of a poster, facing it."""
        goals: dict[str, NDArray[np.float64]] = {}
        for p in self.posters:
            f = self.faces[p.face]
            reg = self.regions[f.region]
            if reg.kind != "room" or reg.name in goals:
                continue
            mid = p.s0 + p.width / 2
            along = f.lo + mid if _s_increasing(f) else f.hi - mid
            for dist in (2.5, 2.0, 1.6, 3.0):
                if f.axis == 0:
                    xy = np.array([f.c + f.normal * dist, along])
                    yaw = np.pi if f.normal > 0 else 0.0
                else:
                    xy = np.array([along, f.c + f.normal * dist])
                    yaw = -np.pi / 2 if f.normal > 0 else np.pi / 2
                if self.is_free(xy, 0.45) and self.region_at(xy) == reg.label:
                    goals[reg.name] = pose2d(xy[0], xy[1], yaw)
                    break
        return goals

    # ----------------------------------------------------------------- queries
    @cached_property
    def wall_segments(self) -> NDArray[np.float64]:
        """(N, 4) x0, y0, x1, y1 of every wall face and box face (for collisions/plots)."""
        segs = []
        for f in self.faces:
            if f.axis == 0:
                segs.append((f.c, f.lo, f.c, f.hi))
            else:
                segs.append((f.lo, f.c, f.hi, f.c))
        return np.array(segs, dtype=np.float64).reshape(-1, 4)

    def region_at(self, xy: NDArray[np.floating]) -> int:
        """Label of the region containing point xy (0 = solid / outside)."""
        c = self.spec.cell
        j, i = int(np.floor(xy[0] / c)), int(np.floor(xy[1] / c))
        if 0 <= i < self.labels.shape[0] and 0 <= j < self.labels.shape[1]:
            return int(self.labels[i, j])
        return 0

    def clearance(self, xy: NDArray[np.floating]) -> NDArray[np.float64]:
        """Distance (m) from each of (N, 2) points to the nearest wall or box face; 0 outside."""
        P = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        S = self.wall_segments
        a, b = S[None, :, :2], S[None, :, 2:]
        ab = b - a
        t = np.clip(
            np.sum((P[:, None, :] - a) * ab, -1) / np.maximum(np.sum(ab * ab, -1), 1e-12), 0, 1
        )
        d = np.linalg.norm(P[:, None, :] - (a + t[..., None] * ab), axis=-1).min(axis=1)
        inside = np.array([self.region_at(p) > 0 for p in P])
        if len(self.boxes):
            B = self.boxes
            in_box = (
                (P[:, None, 0] > B[None, :, 0])
                & (P[:, None, 0] < B[None, :, 2])
                & (P[:, None, 1] > B[None, :, 1])
                & (P[:, None, 1] < B[None, :, 3])
            ).any(axis=1)
            inside &= ~in_box
        return np.where(inside, d, 0.0)

    def is_free(self, xy: NDArray[np.floating], radius: float) -> bool:
        """True if a disc of `radius` metres at xy (world) touches no wall or box."""
        dist, res = self.clearance_grid
        i, j = int(xy[1] / res), int(xy[0] / res)
        if 0 <= i < dist.shape[0] and 0 <= j < dist.shape[1] and dist[i, j] > radius + 2.5 * res:
            return (
                True  # far from everything on the grid (grid error < 2 cells): skip the exact test
            )
        return bool(self.clearance(np.asarray(xy, dtype=np.float64)[:2])[0] > radius)

    @cached_property
    def clearance_grid(self) -> tuple[NDArray[np.float32], float]:
        """(H, W) clearance map (m) on a 0.1 m grid over `bounds`, and its resolution."""
        res = 0.1
        x0, y0, x1, y1 = self.bounds
        W, H = int(np.ceil((x1 - x0) / res)), int(np.ceil((y1 - y0) / res))
        occ = np.full((H, W), 255, np.uint8)
        lab_up = cv2.resize(self.labels.astype(np.float32), (W, H), interpolation=cv2.INTER_NEAREST)
        occ[lab_up == 0] = 0
        for sx0, sy0, sx1, sy1 in self.wall_segments:
            p0 = (round(sx0 / res), round(sy0 / res))
            p1 = (round(sx1 / res), round(sy1 / res))
            cv2.line(occ, p0, p1, 0, 1)
        for bx0, by0, bx1, by1, _ in self.boxes:
            cv2.rectangle(
                occ,
                (int(bx0 / res), int(by0 / res)),
                (int(np.ceil(bx1 / res)), int(np.ceil(by1 / res))),
                0,
                -1,
            )
        dist = cv2.distanceTransform(occ, cv2.DIST_L2, 5).astype(np.float32) * res
        return dist, res

    def room_centre(self, label: int) -> NDArray[np.float64]:
        """The point of a region farthest from walls and boxes."""
        dist, res = self.clearance_grid
        lab_up = cv2.resize(
            self.labels.astype(np.float32),
            (dist.shape[1], dist.shape[0]),
            interpolation=cv2.INTER_NEAREST,
        )
        d = np.where(lab_up == label, dist, -1)
        i, j = np.unravel_index(int(np.argmax(d)), d.shape)
        return np.array([(j + 0.5) * res, (i + 0.5) * res])

    def summary(self) -> dict[str, object]:
        x0, y0, x1, y1 = self.bounds
        return {
            "name": self.spec.name,
            "seed": self.spec.seed,
            "size_m": [x1 - x0, y1 - y0],
            "regions": len(self.regions),
            "rooms": sum(r.kind == "room" for r in self.regions.values()),
            "doors": len(self.doors),
            "faces": len(self.faces),
            "boxes": len(self.boxes),
            "posters": len(self.posters),
            "goal_places": sorted(self.goal_places),
        }


def _s_increasing(f: Face) -> bool:
    """Whether a face's texture coordinate s grows with the world coordinate along it.

    s runs left to right as seen by a viewer facing the face (z up).
    """
    # viewer looks along -n; right = (f_y, -f_x). Axis 0 (plane x=c): n=(normal,0) ->
    # right = (0, normal): s grows with y iff normal > 0. Axis 1: n=(0,normal) -> right =
    # (-normal, 0): s grows with x iff normal < 0.
    return f.normal > 0 if f.axis == 0 else f.normal < 0


def pose2d(x: float, y: float, yaw: float) -> NDArray[np.float64]:
    """4x4 pose of base_link on the ground plane at (x, y) with heading yaw (radians)."""
    T = np.eye(4)
    c, s = np.cos(yaw), np.sin(yaw)
    T[:2, :2] = [[c, -s], [s, c]]
    T[0, 3], T[1, 3] = x, y
    return T
