"""The parts a generated building is made of: wall faces, regions, pictures on walls.

World frame: z up, metres; the floor is z = 0. A face is a vertical textured rectangle in a
plane x = c (axis 0) or y = c (axis 1), seen from the side its `normal` points to; its
texture coordinate s runs left to right as seen by a viewer facing it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import NDArray

PictureKind = Literal["photo", "poster", "print", "notice", "sign", "plate"]


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
    """A picture on a wall face: face index, s (m along the face), z0 (m, its lower edge),
    size (m) and what it shows.

    `kind` "photo": `image` is a photograph's file name in scikit-image's data folder (the
    aliased appearance). Otherwise the picture is generated (`litevloc.sim.pictures`) from
    `design` (an integer seed; two pictures of a building with the same kind and design
    look the same) and `text` (the words printed on it: a room number, a sign's message).
    """

    face: int
    s0: float
    z0: float
    width: float
    height: float
    image: str
    kind: PictureKind = "photo"
    design: int = -1
    text: tuple[str, ...] = ()

    @property
    def key(self) -> tuple[str, str, int, tuple[str, ...]]:
        """What the picture shows: equal keys, equal pictures."""
        return (self.kind, self.image if self.kind == "photo" else "", self.design, self.text)


@dataclass
class Region:
    label: int
    name: str
    kind: Literal["room", "corridor"]
    material: str = "painted"
    cells: int = 0
    bbox: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)  # x0, y0, x1, y1
    neighbours: list[int] = field(default_factory=list)
    number: str = ""  # the number on its door plate (varied appearance), e.g. "1.04"


def s_increasing(f: Face) -> bool:
    """Whether a face's texture coordinate s grows with the world coordinate along it.

    s runs left to right as seen by a viewer facing the face (z up).
    """
    # viewer looks along -n; right = (f_y, -f_x). Axis 0 (plane x=c): n=(normal,0) ->
    # right = (0, normal): s grows with y iff normal > 0. Axis 1: n=(0,normal) -> right =
    # (-normal, 0): s grows with x iff normal < 0.
    return f.normal > 0 if f.axis == 0 else f.normal < 0


def face_point(f: Face, s: float) -> NDArray[np.float64]:
    """(2,) world xy of the point at texture coordinate s (m) along face f."""
    along = f.lo + s if s_increasing(f) else f.hi - s
    return np.array([f.c, along]) if f.axis == 0 else np.array([along, f.c])


def pose2d(x: float, y: float, yaw: float) -> NDArray[np.float64]:
    """4x4 pose of base_link on the ground plane at (x, y) with heading yaw (radians)."""
    T = np.eye(4)
    c, s = np.cos(yaw), np.sin(yaw)
    T[:2, :2] = [[c, -s], [s, c]]
    T[0, 3], T[1, 3] = x, y
    return T
