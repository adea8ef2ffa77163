"""Goal places: where the goal images of a building are taken, by a rule fixed in advance.

Rule "person" (the default; chosen before any navigation result and not tuned since), one
goal per room, drawn from the room's own stream (`default_rng([world seed, 4, label])`):

1. The spot: uniform among the room's free cells (0.1 m grid) that stand `SPOT_CLEAR_M`
   from every wall and box, that the robot can reach from the building's main free space,
   and that lie in the outer part of the room (at least `OUTER_FRACTION` of the way from
   the middle of its free space to the farthest such cell): where a person stands to take
   a picture of a room.
2. The heading: toward the middle of the room's free space (mean of its free cells), turned
   by a uniform angle in +-`HEADING_JITTER_DEG`. A draw whose view is blocked within
   `MIN_VIEW_M` (a box or wall right in front) is drawn again (up to 30 times; then the most
   open draw is kept).
3. Two cameras at that spot and heading: the robot's camera (the robot standing there:
   `T_world_base`), and a hand-held camera: `HAND_FORWARD_M` in front of the spot at a height
   uniform in `HAND_HEIGHT_M`, pitched down by a uniform angle in `HAND_PITCH_DEG` and rolled
   by one in +-`HAND_ROLL_DEG` (`T_world_camera_hand`; optical frame x right, y down, z forward).

Rule "poster" (the first simulator's): ~2.5 m in front of a poster, facing it, robot camera;
its hand-held camera is drawn as above at the same spot and heading.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import cv2
import numpy as np
from numpy.typing import NDArray

from litevloc.base.geometry import make_T, so3_exp
from litevloc.sim.elements import Face, Poster, Region, pose2d, s_increasing

SPOT_CLEAR_M = 0.6
HEADING_JITTER_DEG = 35.0
OUTER_FRACTION = 0.4
MIN_VIEW_M = 2.0
HAND_FORWARD_M = 0.25
HAND_HEIGHT_M = (1.2, 1.6)
HAND_PITCH_DEG = (0.0, 15.0)
HAND_ROLL_DEG = 4.0
REACH_CLEAR_M = 0.4  # free space the robot (radius 0.3 m) drives in, with a margin
# optical frame (x right, y down, z forward) in a level body frame (x forward, y left, z up)
_R_BODY_OPTICAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


class FreeSpace(Protocol):
    """What the rule needs of a building (`litevloc.sim.world.World` provides it)."""

    labels: NDArray[np.int32]
    regions: dict[int, Region]

    @property
    def clearance_grid(self) -> tuple[NDArray[np.float32], float]: ...

    def region_at(self, xy: NDArray[np.floating]) -> int: ...

    def is_free(self, xy: NDArray[np.floating], radius: float) -> bool: ...


@dataclass(frozen=True)
class GoalView:
    """One room's goal: where the robot stands for the robot-camera image (4x4 `T_world_base`,
    level) and the hand-held camera's pose (4x4 `T_world_camera_hand`, optical frame)."""

    T_world_base: NDArray[np.float64]
    T_world_camera_hand: NDArray[np.float64]


def hand_camera(xy: NDArray[np.floating], yaw: float, rng: np.random.Generator) -> NDArray[np.float64]:
    """4x4 T_world_camera of a hand-held camera a person at xy facing yaw holds (see rule 3)."""
    height = rng.uniform(*HAND_HEIGHT_M)
    pitch = np.radians(rng.uniform(*HAND_PITCH_DEG))
    roll = np.radians(rng.uniform(-HAND_ROLL_DEG, HAND_ROLL_DEG))
    R_body = so3_exp(np.array([0.0, 0.0, yaw])) @ so3_exp(np.array([0.0, pitch, 0.0])) \
        @ so3_exp(np.array([roll, 0.0, 0.0]))
    p = np.array([xy[0] + HAND_FORWARD_M * np.cos(yaw), xy[1] + HAND_FORWARD_M * np.sin(yaw), height])
    return make_T(R_body @ _R_BODY_OPTICAL, p)


def _grid_labels(space: FreeSpace, shape: tuple[int, int]) -> NDArray[np.int32]:
    lab = cv2.resize(space.labels.astype(np.float32), (shape[1], shape[0]), interpolation=cv2.INTER_NEAREST)
    return lab.astype(np.int32)


def reachable(space: FreeSpace) -> NDArray[np.bool_]:
    """(H, W) cells of the clearance grid in the building's largest connected free space
    (clearance > `REACH_CLEAR_M`): where the robot can drive."""
    dist, _res = space.clearance_grid
    free = (dist > REACH_CLEAR_M).astype(np.uint8)
    n, comp = cv2.connectedComponents(free, connectivity=8)
    if n <= 1:
        return np.zeros(dist.shape, bool)
    sizes = np.bincount(comp.ravel())[1:]
    return np.asarray(comp == 1 + int(np.argmax(sizes)))


def view_length(space: FreeSpace, xy: NDArray[np.floating], yaw: float, max_m: float = 4.0) -> float:
    """How far (m) a ray from xy along yaw stays in free space (clearance > 0.05 m), up to max_m."""
    dist, res = space.clearance_grid
    d = np.array([np.cos(yaw), np.sin(yaw)])
    for t in np.arange(0.0, max_m, res / 2):
        p = np.asarray(xy, np.float64) + t * d
        i, j = int(p[1] / res), int(p[0] / res)
        if not (0 <= i < dist.shape[0] and 0 <= j < dist.shape[1]) or dist[i, j] <= 0.05:
            return float(t)
    return float(max_m)


def person_goals(space: FreeSpace, seed: int) -> dict[str, GoalView]:
    """One goal per room by rule "person" (module docstring); rooms without a free spot get none."""
    dist, res = space.clearance_grid
    lab = _grid_labels(space, dist.shape)
    reach = reachable(space)
    out: dict[str, GoalView] = {}
    for label, reg in space.regions.items():
        if reg.kind != "room":
            continue
        rng = np.random.default_rng([seed, 4, label])
        ii, jj = np.nonzero((lab == label) & reach & (dist >= SPOT_CLEAR_M))
        mi, mj = np.nonzero((lab == label) & (dist > 0.3))
        if len(ii) == 0 or len(mi) == 0:
            continue
        middle = (np.array([mj.mean(), mi.mean()]) + 0.5) * res
        from_mid = np.hypot((jj + 0.5) * res - middle[0], (ii + 0.5) * res - middle[1])
        outer = from_mid >= OUTER_FRACTION * from_mid.max()
        ii, jj = ii[outer], jj[outer]
        best: tuple[float, NDArray[np.float64], float] | None = None
        for _ in range(30):
            k = int(rng.integers(len(ii)))
            xy = (np.array([jj[k], ii[k]], np.float64) + 0.5) * res
            to_mid = middle - xy
            yaw = float(np.arctan2(to_mid[1], to_mid[0]) + np.radians(rng.uniform(-1, 1) * HEADING_JITTER_DEG))
            view = view_length(space, xy, yaw)
            if best is None or view > best[0]:
                best = (view, xy, yaw)
            if view >= MIN_VIEW_M:
                break
        assert best is not None
        _, xy, yaw = best
        out[reg.name] = GoalView(pose2d(xy[0], xy[1], yaw), hand_camera(xy, yaw, rng))
    return out


def poster_goals(space: FreeSpace, faces: list[Face], posters: list[Poster], seed: int) -> dict[str, GoalView]:
    """One goal per room by rule "poster": a free spot ~2.5 m in front of the room's first
    poster, facing it (the first simulator's rule)."""
    out: dict[str, GoalView] = {}
    for p in posters:
        f = faces[p.face]
        reg = space.regions[f.region]
        if reg.kind != "room" or reg.name in out:
            continue
        mid = p.s0 + p.width / 2
        along = f.lo + mid if s_increasing(f) else f.hi - mid
        for dist in (2.5, 2.0, 1.6, 3.0):
            if f.axis == 0:
                xy = np.array([f.c + f.normal * dist, along])
                yaw = np.pi if f.normal > 0 else 0.0
            else:
                xy = np.array([along, f.c + f.normal * dist])
                yaw = -np.pi / 2 if f.normal > 0 else np.pi / 2
            if space.is_free(xy, 0.45) and space.region_at(xy) == reg.label:
                rng = np.random.default_rng([seed, 4, reg.label])
                out[reg.name] = GoalView(pose2d(xy[0], xy[1], yaw), hand_camera(xy, yaw, rng))
                break
    return out
