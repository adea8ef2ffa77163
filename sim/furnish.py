"""Furniture and clutter: axis-aligned boxes standing in the rooms of a floor plan.

Furniture (cabinets, shelves, desks, pillars) stands against the walls, away from doors,
drawn from the building's main random stream. Clutter (bins, plant pots, stools, crates:
small things a real room has) is drawn from its own stream, so a building with and without
clutter has the same furniture. Boxes are (N, 5) x0, y0, x1, y1, height (m).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from litevloc.sim.elements import Face, Region
from litevloc.sim.layout import Door
from litevloc.sim.spec import WorldSpec

FURNITURE_KINDS = ("cabinet", "shelf", "desk", "pillar")
CLUTTER_KINDS = ("bin", "plant", "stool", "crate")
DOOR_CLEAR_M = 1.3  # nothing stands nearer a door's centre: doorways stay passable
BOX_GAP_M = 0.9  # boxes at least this far apart: the robot (0.6 m wide) passes between them


def door_centres(doors: list[Door]) -> NDArray[np.float64]:
    """(D, 2) centre of every door (m)."""
    return np.array([((d[2] + d[4]) / 2, (d[3] + d[5]) / 2) for d in doors]).reshape(-1, 2)


def _near_door(bx: NDArray[np.float64], door_pts: NDArray[np.float64]) -> bool:
    if not len(door_pts):
        return False
    dx = np.maximum(np.maximum(bx[0] - door_pts[:, 0], door_pts[:, 0] - bx[2]), 0)
    dy = np.maximum(np.maximum(bx[1] - door_pts[:, 1], door_pts[:, 1] - bx[3]), 0)
    return bool(np.any(np.hypot(dx, dy) < DOOR_CLEAR_M))


def overlaps(bx: NDArray[np.float64], boxes: Sequence[tuple[float, ...]] | NDArray[np.float64], gap: float,
              skip: int = -1) -> bool:
    return any(bx[0] < o[2] + gap and o[0] < bx[2] + gap and bx[1] < o[3] + gap and o[1] < bx[3] + gap
               for j, o in enumerate(boxes) if j != skip)


def legacy_kind(height: float, wall_height: float) -> str:
    """A furniture box's kind from its height (how the first simulator told them apart)."""
    if height >= wall_height - 1e-6:
        return "pillar"
    return "desk" if height < 0.8 else "shelf" if height > 1.5 else "cabinet"


def make_furniture(spec: WorldSpec, regions: dict[int, Region], doors: list[Door],
                   rng: np.random.Generator) -> NDArray[np.float64]:
    """(N, 5) furniture boxes against the walls of every room (drawn from `rng`)."""
    s = spec
    boxes: list[tuple[float, float, float, float, float]] = []
    door_pts = door_centres(doors)
    kinds = [
        ("cabinet", (0.6, 1.4), (0.4, 0.6), (0.8, 1.1)),
        ("shelf", (0.8, 1.8), (0.3, 0.45), (1.6, 2.1)),
        ("desk", (1.0, 1.8), (0.6, 0.8), (0.72, 0.78)),
        ("pillar", (0.4, 0.6), (0.4, 0.6), (s.wall_height, s.wall_height)),
    ]
    for reg in regions.values():
        if reg.kind != "room":
            continue
        x0, y0, x1, y1 = reg.bbox
        n = int(rng.integers(s.furniture_per_room[0], s.furniture_per_room[1] + 1))
        for _ in range(n * 6):
            if n <= 0:
                break
            kind, (la, lb), (da, db), (ha, hb) = kinds[int(rng.choice(4, p=[0.35, 0.3, 0.3, 0.05]))]
            length, depth, h = rng.uniform(la, lb), rng.uniform(da, db), rng.uniform(ha, hb)
            side = int(rng.integers(4))
            gap = 0.05
            if side in (0, 1):  # against the west / east wall
                if y1 - y0 < length + 1.0:
                    continue
                by0 = rng.uniform(y0 + 0.3, y1 - 0.3 - length)
                bx0 = x0 + gap if side == 0 else x1 - gap - depth
                box = (bx0, by0, bx0 + depth, by0 + length, h)
            else:
                if x1 - x0 < length + 1.0:
                    continue
                bx0 = rng.uniform(x0 + 0.3, x1 - 0.3 - length)
                by0 = y0 + gap if side == 2 else y1 - gap - depth
                box = (bx0, by0, bx0 + length, by0 + depth, h)
            if kind == "pillar":
                cx, cy = rng.uniform(x0 + 1.5, x1 - 1.5), rng.uniform(y0 + 1.5, y1 - 1.5)
                if x1 - x0 < 5 or y1 - y0 < 5:
                    continue
                box = (cx - depth / 2, cy - length / 2 * 0.5, cx + depth / 2, cy + length / 2 * 0.5, h)
            bx = np.array(box[:4])
            # keep doors clear and boxes apart (passages stay open)
            if _near_door(bx, door_pts) or overlaps(bx, boxes, BOX_GAP_M):
                continue
            boxes.append(box)
            n -= 1
    return np.array(boxes, dtype=np.float64).reshape(-1, 5)


def make_clutter(spec: WorldSpec, regions: dict[int, Region], doors: list[Door], boxes: NDArray[np.float64],
                 rng: np.random.Generator) -> tuple[NDArray[np.float64], list[str]]:
    """(M, 5) clutter boxes and their kinds: `clutter_per_room` per room, most against a wall
    (5 cm off it), some free-standing with `BOX_GAP_M` to every wall and box."""
    placed: list[tuple[float, ...]] = [tuple(b) for b in boxes]
    out: list[tuple[float, float, float, float, float]] = []
    kinds: list[str] = []
    door_pts = door_centres(doors)
    sizes = {"bin": ((0.3, 0.42), (0.4, 0.75)), "plant": ((0.35, 0.5), (0.6, 1.1)),
             "stool": ((0.38, 0.5), (0.45, 0.9)), "crate": ((0.4, 0.6), (0.35, 0.6))}
    lo_n, hi_n = spec.clutter_per_room
    for reg in regions.values():
        if reg.kind != "room" or hi_n == 0:
            continue
        x0, y0, x1, y1 = reg.bbox
        n = int(rng.integers(lo_n, hi_n + 1))
        for _ in range(n * 8):
            if n <= 0:
                break
            kind = CLUTTER_KINDS[int(rng.integers(len(CLUTTER_KINDS)))]
            (sa, sb), (ha, hb) = sizes[kind]
            w, d, h = rng.uniform(sa, sb), rng.uniform(sa, sb), rng.uniform(ha, hb)
            if rng.random() < 0.7:  # against a wall
                side = int(rng.integers(4))
                if side < 2:
                    by0 = rng.uniform(y0 + 0.3, y1 - 0.3 - d)
                    bx0 = x0 + 0.05 if side == 0 else x1 - 0.05 - w
                else:
                    bx0 = rng.uniform(x0 + 0.3, x1 - 0.3 - w)
                    by0 = y0 + 0.05 if side == 2 else y1 - 0.05 - d
            else:
                bx0 = rng.uniform(x0 + BOX_GAP_M, x1 - BOX_GAP_M - w)
                by0 = rng.uniform(y0 + BOX_GAP_M, y1 - BOX_GAP_M - d)
            bx = np.array([bx0, by0, bx0 + w, by0 + d])
            if _near_door(bx, door_pts) or overlaps(bx, placed, BOX_GAP_M):
                continue
            placed.append((*bx, h))
            out.append((float(bx[0]), float(bx[1]), float(bx[2]), float(bx[3]), float(h)))
            kinds.append(kind)
            n -= 1
    return np.array(out, dtype=np.float64).reshape(-1, 5), kinds


def box_faces(boxes: NDArray[np.float64]) -> list[Face]:
    """The four faces of every box, in box order (west, east, south, north)."""
    faces = []
    for k, (bx0, by0, bx1, by1, h) in enumerate(boxes):
        faces.append(Face(0, bx0, by0, by1, -1, h, 0, "box", k))
        faces.append(Face(0, bx1, by0, by1, +1, h, 0, "box", k))
        faces.append(Face(1, by0, bx0, bx1, -1, h, 0, "box", k))
        faces.append(Face(1, by1, bx0, bx1, +1, h, 0, "box", k))
    return faces


def slide_furniture(boxes: NDArray[np.float64], kinds: list[str], doors: list[Door], regions: dict[int, Region],
                    region_of: list[int], rng: np.random.Generator, fraction: float) -> tuple[NDArray[np.float64], int]:
    """A `fraction` of the furniture (pillars and clutter excepted) slid 0.5-1.5 m along its
    wall where the room allows (the same building months later); returns the boxes and how
    many moved. `region_of[k]`: the region label under box k's centre."""
    door_pts = door_centres(doors)
    boxes = boxes.copy()
    moved = 0
    for k in range(len(boxes)):
        if kinds[k] not in FURNITURE_KINDS or kinds[k] == "pillar" or rng.random() >= fraction:
            continue
        reg = regions.get(region_of[k])
        if reg is not None and slide_box(boxes, k, reg, door_pts, rng):
            moved += 1
    return boxes, moved


def slide_box(boxes: NDArray[np.float64], k: int, reg: Region, door_pts: NDArray[np.float64],
              rng: np.random.Generator) -> bool:
    """Slide box k (in place) 0.5-1.5 m along its long side, staying in room `reg`, clear of
    doors and `BOX_GAP_M` from the other boxes (10 tries); whether it moved."""
    bx0, by0, bx1, by1, _h = boxes[k]
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
        if _near_door(nb, door_pts) or overlaps(nb, boxes, BOX_GAP_M, skip=k):
            continue
        boxes[k] = nb
        return True
    return False
