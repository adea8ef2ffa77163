"""Unmapped openings of an occupancy grid: a doorway into an unseen room is listed, with where
it is, its width and which way it leads; wall gaps, shadows and speckle are not."""

from __future__ import annotations

import numpy as np

from litevloc.base.params.navigation import OpeningParams
from litevloc.pipelines.topomap.keyframes import plane_axes
from litevloc.pipelines.topomap.openings import find_openings, mapped_free, openings_summary
from litevloc.pipelines.topomap.types import OccupancyGrid

RES = 0.1
UP = np.array([0.0, 0.0, 1.0])


def two_rooms(room_b: int = OccupancyGrid.UNKNOWN) -> OccupancyGrid:
    """Plane cells (row = plane y, col = plane x): room A (x 0-4 m) mapped free, room B (x 4-8 m)
    `room_b`, walls around both and between them with a 1 m door at plane y 1.5-2.5 m."""
    cells = np.zeros((42, 82), np.uint8)
    cells[1:41, 1:41] = OccupancyGrid.FREE
    cells[1:41, 41:81] = room_b
    cells[0, :] = cells[41, :] = cells[:, 0] = cells[:, 81] = OccupancyGrid.OCCUPIED
    cells[:, 40] = OccupancyGrid.OCCUPIED
    cells[15:25, 40] = OccupancyGrid.FREE  # the doorway (10 cells = 1 m), seen from room A
    return OccupancyGrid(cells, np.zeros(2), RES, UP, plane_axes(UP))


def test_a_doorway_into_an_unseen_room_is_one_opening() -> None:
    grid = two_rooms()
    (o,) = find_openings(grid)
    assert 0.9 <= o.width_m <= 1.3
    assert abs(o.centre_xy[0] - 4.05) < 0.2 and abs(o.centre_xy[1] - 2.0) < 0.2  # in the doorway
    d = o.direction @ grid.plane_axes.T  # back to plane coordinates: into room B (+x)
    assert d[0] > 0.8
    assert o.unknown_m2 > 3.0
    assert np.allclose(grid.to_plane(o.position[None]), o.centre_xy[None])
    (row,) = openings_summary([o])
    assert set(row) == {"x", "y", "z", "width_m", "direction", "unknown_m2"}


def test_a_mapped_room_behind_the_door_leaves_no_opening() -> None:
    assert find_openings(two_rooms(room_b=OccupancyGrid.FREE)) == []


def test_wall_gaps_shadows_and_speckle_are_not_openings() -> None:
    grid = two_rooms()
    c = grid.cells
    c[28:36:2, 40] = OccupancyGrid.UNKNOWN  # a wall seen from afar: every other point missing
    c[5:7, 5:15] = OccupancyGrid.OCCUPIED  # a cabinet ...
    c[7:12, 5:15] = OccupancyGrid.UNKNOWN  # ... and its 1 m wide, 0.5 m^2 shadow
    c[20:36:3, 10:30:4] = OccupancyGrid.UNKNOWN  # a floor seen from afar: speckle
    (o,) = find_openings(grid)  # still only the doorway
    assert abs(o.centre_xy[1] - 2.0) < 0.2
    # without their rules the shadow is an opening and the speckle is unknown space
    assert len(find_openings(grid, OpeningParams(min_unknown_m2=0.0))) == 2
    assert mapped_free(grid)[20, 10] and not mapped_free(grid, OpeningParams(close_m=0.0))[20, 10]
    # a gap as wide as a door in the outer wall of the mapped room is an opening (unknown beyond)
    c[0, 10:20] = OccupancyGrid.FREE
    grid2 = OccupancyGrid(np.pad(c, ((20, 0), (0, 0))), np.array([0.0, -2.0]), RES, UP, plane_axes(UP))
    assert len(find_openings(grid2)) == 2
