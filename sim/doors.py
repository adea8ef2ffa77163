"""Door leaves for a changed building: doorways of the generated plan are open gaps; a changed
building hangs a leaf in some of them, closed (a panel filling the doorway, so routes go round
by another door) or standing open at 90 degrees against the jamb (the doorway stays passable).

A leaf is a thin box (`LEAF_THICKNESS_M`, `min(2.1 m, wall height - 0.1 m)` high) of kind "door".
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from litevloc.sim.layout import Door

LEAF_THICKNESS_M = 0.04
LEAF_SHARE_OF_WIDTH = 0.95  # an open leaf is a little narrower than its doorway


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


def _leaf_box(door: Door, closed: bool, side: float, hinge_low: bool, height: float) -> tuple[float, ...]:
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
        b0, b1 = (lo, lo + t) if hinge_low else (hi - t, hi)
    box = (a0, b0, a1, b1) if plane_x else (b0, a0, b1, a1)
    return (*box, height)


def hang_leaves(doors: list[Door], regions: set[int], fraction: float, wall_height: float,
                rng: np.random.Generator) -> list[DoorLeaf]:
    """Leaves in a `fraction` of the doorways (drawn from `rng`): closed (half of them) where every
    region stays reachable through the doors left open, else open at 90 degrees."""
    height = min(2.1, wall_height - 0.1)
    open_pairs = [(d[0], d[1]) for d in doors]
    leaves = []
    for i, door in enumerate(doors):
        if rng.random() >= fraction:
            continue
        want_closed = rng.random() < 0.5
        side, hinge_low = float(rng.choice([-1.0, 1.0])), bool(rng.random() < 0.5)
        rest = open_pairs.copy()
        rest.remove((door[0], door[1]))
        closed = want_closed and _connected(rest, regions)
        if closed:
            open_pairs = rest
        leaves.append(DoorLeaf(i, closed, _leaf_box(door, closed, side, hinge_low, height)))  # type: ignore[arg-type]
    return leaves


def leaf_boxes(leaves: list[DoorLeaf]) -> NDArray[np.float64]:
    """(N, 5) boxes of the leaves."""
    return np.array([lf.box for lf in leaves], dtype=np.float64).reshape(-1, 5)
