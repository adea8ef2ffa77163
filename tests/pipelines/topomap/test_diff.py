"""Map diff: identity by keyframe image, moved/added/retired, coverage on a common grid."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from numpy.typing import NDArray

from litevloc.base import geometry as g
from litevloc.base.params.map_maintenance import DiffParams
from litevloc.pipelines.topomap.diff import MapDiffError, coverage_diff, diff_maps
from litevloc.pipelines.topomap.types import NodeFeatures, OccupancyGrid, TopoMap

UP = np.array([0.0, 0.0, 1.0])
AXES = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


def grid(cols: slice, rows: slice, res: float = 0.5, origin: tuple[float, float] = (0.0, 0.0)) -> OccupancyGrid:
    cells = np.zeros((20, 20), np.uint8)
    cells[rows, cols] = OccupancyGrid.FREE
    return OccupancyGrid(cells, np.asarray(origin, np.float64), res, UP, AXES)


def camera(x: float, y: float, yaw_deg: float = 0.0) -> NDArray[np.float64]:
    """Camera at (x, y, 0.5) looking along map +x rotated by yaw (optical z forward)."""
    R_look = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])  # optical axes in a z-up world
    R = g.so3_exp(np.array([0.0, 0.0, np.radians(yaw_deg)])) @ R_look
    return g.make_T(R, [x, y, 0.5])


def make_map(poses: list[NDArray[np.float64]], images: list[bytes], occ: OccupancyGrid) -> TopoMap:
    n = len(poses)
    feats = [NodeFeatures(np.zeros((0, 2), np.float32), np.zeros((0, 8), np.float32), np.zeros(0, np.float32),
                          (64, 48)) for _ in range(n)]
    e = np.zeros((0, 2), np.int64)
    return TopoMap(np.stack(poses), np.stack([np.eye(3)] * n), np.array([[64, 48]] * n, np.int32),
                   np.arange(n, dtype=np.int64), np.arange(n, dtype=np.int64), np.eye(n, 4, dtype=np.float32),
                   feats, images, e, np.zeros(0, np.int32), np.zeros(0, np.float32), e, np.zeros(0, np.float32), occ)


def test_identical_maps_have_no_changes() -> None:
    m = make_map([camera(0, 0), camera(2, 0)], [b"a", b"b"], grid(slice(0, 10), slice(0, 4)))
    d = diff_maps(m, m)
    s = d.summary()
    assert (s["kept"], s["moved"], s["added"], s["retired"]) == (2, 0, 0, 0)
    assert s["coverage_only_old_m2"] == s["coverage_only_new_m2"] == 0.0
    assert s["coverage_old_m2"] == pytest.approx(10 * 4 * 0.25)
    assert d.old_places_kept == d.new_places_in_old == 1.0


def test_added_retired_moved_by_image_identity() -> None:
    old = make_map([camera(0, 0), camera(2, 0), camera(4, 0)], [b"a", b"b", b"c"], grid(slice(0, 10), slice(0, 4)))
    # "b" moved 5 cm, "c" retired, "d" added far away; node order differs in the new map.
    new = make_map([camera(8, 0), camera(2.05, 0), camera(0, 0)], [b"d", b"b", b"a"],
                   grid(slice(0, 18), slice(0, 4)))
    d = diff_maps(old, new)
    assert sorted(map(tuple, d.kept.tolist())) == [(0, 2), (1, 1)]
    assert d.retired.tolist() == [2] and d.added.tolist() == [0]
    assert len(d.moved) == 1 and tuple(d.kept[d.moved[0]]) == (1, 1)
    assert d.moved_m[0] == pytest.approx(0.05)
    # old place at x=4 has no new keyframe within 0.5 m: 2 of 3 old places kept
    assert d.old_places_kept == pytest.approx(2 / 3)
    assert d.new_places_in_old == pytest.approx(2 / 3)
    c = d.coverage
    assert c.only_new_m2 == pytest.approx(8 * 4 * 0.25) and c.only_old_m2 == 0.0
    # a larger tolerance turns the 5 cm move into "kept in place"
    assert len(diff_maps(old, new, DiffParams(moved_m=0.1)).moved) == 0


def test_rotation_counts_as_moved_and_place_angle() -> None:
    old = make_map([camera(0, 0)], [b"a"], grid(slice(0, 2), slice(0, 2)))
    new = make_map([camera(0, 0, yaw_deg=90)], [b"a"], grid(slice(0, 2), slice(0, 2)))
    d = diff_maps(old, new)
    assert len(d.moved) == 1 and d.moved_deg[0] == pytest.approx(90, abs=1e-6)
    assert d.old_places_kept == 0.0  # same spot, but looking 90 deg away (> 45 deg)


def test_coverage_on_common_grid_with_other_origin_and_resolution() -> None:
    a = grid(slice(0, 4), slice(0, 4), res=0.5)  # [0, 2] x [0, 2]
    b = grid(slice(0, 8), slice(0, 4), res=0.25, origin=(1.0, 0.0))  # [1, 3] x [0, 1]
    c = coverage_diff(a, b)
    assert c.resolution_m == 0.5
    assert c.old_m2 == pytest.approx(4.0) and c.new_m2 == pytest.approx(2.0)
    assert c.both_m2 == pytest.approx(1.0) and c.only_new_m2 == pytest.approx(1.0)


def test_other_ground_plane_is_an_error() -> None:
    a = grid(slice(0, 2), slice(0, 2))
    b = dataclasses.replace(a, up=np.array([0.0, 1.0, 0.0]))
    with pytest.raises(MapDiffError, match="ground planes"):
        coverage_diff(a, b)


def test_params_validated() -> None:
    with pytest.raises(ValueError, match="moved_m"):
        DiffParams(moved_m=float("nan"))
