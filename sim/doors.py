"""Door leaves for a changed building: doorways of the generated plan are open gaps; a changed
building hangs a leaf in some of them, closed (a panel filling the doorway, so routes go round
by another door) or standing open at 90 degrees beside the jamb (the doorway keeps its full width).

A leaf is a thin box (`LEAF_THICKNESS_M`, `min(2.1 m, wall height - 0.1 m)` high) of kind "door".
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from litevloc.sim.furnish import overlaps
from litevloc.sim.layout import Door

LEAF_THICKNESS_M = 0.04
# an open leaf stands this far beside the doorway (past its frame, and clear on the planner's 0.1 m grid)
HINGE_GAP_M = 0.12
LEAF_SHARE_OF_WIDTH = 0.95  # an open leaf is a little narrower than its doorway
LEAF_GAP_M = 0.7  # an open leaf this far from every box: the robot (0.6 m wide) passes


@dataclass(frozen=True)
class DoorLeaf:
    """A leaf hung in doorway `door` (index into World.doors): its box (x0, y0, x1, y1, height, m)."""

    door: int
    closed: bool
    box: tuple[float, float, float, float, float]


def _connected(n_doors: list[tuple[int, int]], regions: set[int]) -> bool:
    if not regions:
        return True
    graph: dict[int, set[int]] = {r: set() for r in regions}
    for a, b in n_doors:
        graph[a].add(b)
        graph[b].add(a)
    start = next(iter(regions))
    seen, todo = {start}, [start]
    while todo:
        for n in graph[todo.pop()]:
            if n not in seen:
                seen.add(n)
                todo.append(n)
    return seen == regions


def _leaf_box(door: Door, closed: bool, side: float, hinge_low: bool,
              height: float) -> tuple[float, float, float, float, float]:
    """The box of a leaf in doorway `door`: closed across it, or open into the half-plane `side`
    (+1: towards larger x or y) hinged at its low or high end."""
    _a, _b, x0, y0, x1, y1 = door
    t = LEAF_THICKNESS_M
    plane_x = x0 == x1  # the doorway lies in a plane x = c, spanning y0..y1
    c, lo, hi = (x0, y0, y1) if plane_x else (y0, x0, x1)
    if closed:
        a0, a1, b0, b1 = c - t / 2, c + t / 2, lo, hi
    else:
        reach = LEAF_SHARE_OF_WIDTH * (hi - lo)
        a0, a1 = (c, c + reach) if side > 0 else (c - reach, c)
        g = HINGE_GAP_M  # beside the opening, past its frame: the doorway keeps its full width
        b0, b1 = (lo - g - t, lo - g) if hinge_low else (hi + g, hi + g + t)
    return (a0, b0, a1, b1, height) if plane_x else (b0, a0, b1, a1, height)


def _into_room(door: Door, rooms: set[int], region_at: Callable[[NDArray[np.float64]], int],
               rng: np.random.Generator) -> float:
    """The side (+1: larger x or y) an open leaf swings to: into a room (a corridor stays clear)."""
    _a, _b, x0, y0, x1, y1 = door
    mid = np.array([(x0 + x1) / 2, (y0 + y1) / 2])
    normal = np.array([1.0, 0.0]) if x0 == x1 else np.array([0.0, 1.0])
    sides = [s for s in (-1.0, 1.0) if region_at(mid + s * 0.3 * normal) in rooms]
    return float(rng.choice(sides)) if sides else 0.0


def hang_leaves(doors: list[Door], rooms: set[int], regions: set[int], boxes: NDArray[np.float64],
                region_at: Callable[[NDArray[np.float64]], int], fraction: float, wall_height: float,
                rng: np.random.Generator) -> list[DoorLeaf]:
    """Leaves in a `fraction` of the doorways (drawn from `rng`): closed (half of them) where every
    region stays reachable through the doors left open, else open at 90 degrees into a room,
    where it stands `LEAF_GAP_M` clear of every box (else the doorway keeps no leaf)."""
    height = min(2.1, wall_height - 0.1)
    open_pairs = [(d[0], d[1]) for d in doors]
    leaves: list[DoorLeaf] = []
    for i, door in enumerate(doors):
        if rng.random() >= fraction:
            continue
        want_closed = rng.random() < 0.5
        side, hinge_low = _into_room(door, rooms, region_at, rng), bool(rng.random() < 0.5)
        rest = open_pairs.copy()
        rest.remove((door[0], door[1]))
        closed = want_closed and _connected(rest, regions)
        box = _leaf_box(door, closed, side, hinge_low, height)
        others = [*boxes.tolist(), *(lf.box for lf in leaves)]
        if not closed and (side == 0.0 or overlaps(np.array(box[:4]), others, LEAF_GAP_M)):
            continue
        if closed:
            open_pairs = rest
        leaves.append(DoorLeaf(i, closed, box))
    return leaves


def leaf_boxes(leaves: list[DoorLeaf]) -> NDArray[np.float64]:
    """(N, 5) boxes of the leaves."""
    return np.array([lf.box for lf in leaves], dtype=np.float64).reshape(-1, 5)
