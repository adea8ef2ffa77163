"""A changed version of a world: same walls and goal places, other posters, moved furniture."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from litevloc.sim.spec import load_world_spec
from litevloc.sim.world import World, load_world


@pytest.mark.parametrize("world", ["office", "floor"])
def test_changed_world_keeps_walls_and_changes_posters_and_furniture(world: str) -> None:
    base = load_world(world)
    changed = load_world(f"{world}-changed")
    assert load_world_spec(f"{world}-changed").change_seed >= 0
    np.testing.assert_array_equal(base.labels, changed.labels)
    assert [f for f in base.faces if f.kind != "box"] == [f for f in changed.faces if f.kind != "box"]
    assert base.goal_places.keys() == changed.goal_places.keys()
    for k in base.goal_places:
        np.testing.assert_allclose(base.goal_places[k], changed.goal_places[k])
    assert changed.changes["posters"] >= 1 and changed.changes["furniture"] >= 1
    assert sum((a.image, a.design) != (b.image, b.design) for a, b in zip(base.posters, changed.posters, strict=True)) \
        == changed.changes["posters"]  # a photograph changes its image, a generated picture its design
    moved = np.any(np.abs(base.boxes - changed.boxes) > 1e-9, axis=1)
    assert int(moved.sum()) == changed.changes["furniture"]
    # moved boxes keep their size and height and stay apart from the others (0.9 m passages)
    np.testing.assert_allclose(base.boxes[:, 2] - base.boxes[:, 0], changed.boxes[:, 2] - changed.boxes[:, 0])
    np.testing.assert_allclose(base.boxes[:, 4], changed.boxes[:, 4])
    b = changed.boxes
    for i in range(len(b)):
        for j in range(i + 1, len(b)):
            overlap = b[i, 0] < b[j, 2] + 0.9 and b[j, 0] < b[i, 2] + 0.9 and b[i, 1] < b[j, 3] + 0.9 \
                and b[j, 1] < b[i, 3] + 0.9
            assert not (overlap and (moved[i] or moved[j]))
    # every box face follows the (moved) box
    faces = [f for f in changed.faces if f.kind == "box"]
    assert len(faces) == 4 * len(b)


def test_unchanged_world_is_as_generated() -> None:
    spec = load_world_spec("office")
    a, c = World(spec), World(dataclasses.replace(spec, change_seed=-1))
    np.testing.assert_array_equal(a.boxes, c.boxes)
    assert a.changes == {"posters": 0, "furniture": 0}


def test_change_fraction_validated() -> None:
    with pytest.raises(ValueError, match="change_fraction"):
        dataclasses.replace(load_world_spec("office"), change_fraction=1.5)
