"""A building changed along one axis at a time: each axis changes what it should and nothing else."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from litevloc.base.geometry import PinholeIntrinsics
from litevloc.base.loader import ConfigError
from litevloc.base.params.world_change import MIXES, ChangeSpecError, WorldChangeParams, parse_change
from litevloc.cli.main import main
from litevloc.sim.render import Renderer, baked_textures
from litevloc.sim.simulator import add_people
from litevloc.sim.spec import WorldSpec, load_world_spec
from litevloc.sim.world import World

SPEC = WorldSpec(name="t", seed=3, rows=1, cols=3, corridor_width=2.0, furniture_per_room=(3, 4),
                 clutter_per_room=(2, 3), posters_per_room=(2, 3), texels_per_m=32.0)
K = PinholeIntrinsics(fx=70.0, fy=70.0, cx=48.0, cy=36.0, width=96, height=72)


def changed(**levels: float) -> World:
    return World(dataclasses.replace(SPEC, change=WorldChangeParams(seed=5, **levels)))  # type: ignore[arg-type]


@pytest.fixture(scope="module")
def base() -> World:
    return World(SPEC)


def _poses(world: World, n: int = 6) -> list[np.ndarray]:
    """Camera poses (level, 1.2 m high) at room centres, looking along +x, +y, -x, -y."""
    out = []
    R_down = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])  # optical frame of a camera facing +x
    labels = sorted(world.regions)
    for k in range(n):
        c = world.room_centre(labels[k % len(labels)])
        yaw = k * np.pi / 2
        Rz = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]])
        T = np.eye(4)
        T[:3, :3] = Rz @ R_down
        T[:3, 3] = [c[0], c[1], 1.2]
        out.append(T)
    return out


def _renders(world: World, t_ns: int = 0) -> list[tuple[np.ndarray, np.ndarray]]:
    r = Renderer(world)
    out = []
    for T in _poses(world):
        col, dep = r.render(T, K)
        add_people(world, T, K, t_ns, col, dep)
        out.append((col, dep))
    return out


def _walls(w: World) -> list[object]:
    return [f for f in w.faces if f.kind == "wall"]


def test_level_zero_is_the_generated_building_bit_for_bit(base: World) -> None:
    zero = World(dataclasses.replace(SPEC, change=WorldChangeParams(seed=9)))
    assert zero.faces == base.faces and zero.posters == base.posters
    np.testing.assert_array_equal(zero.boxes, base.boxes)
    ta, tb = baked_textures(base), baked_textures(zero)
    np.testing.assert_array_equal(ta.atlas[0], tb.atlas[0])
    np.testing.assert_array_equal(ta.floor, tb.floor)
    for (ca, da), (cb, db) in zip(_renders(base), _renders(zero), strict=True):
        np.testing.assert_array_equal(ca, cb)
        np.testing.assert_array_equal(da, db)


def test_lighting_changes_only_shading(base: World) -> None:
    lit = changed(lighting=1.0)
    assert lit.faces == base.faces and lit.posters == base.posters
    np.testing.assert_array_equal(lit.boxes, base.boxes)
    assert lit.change_truth.lighting["lamps"]
    differs = 0
    for (ca, da), (cb, db) in zip(_renders(base), _renders(lit), strict=True):
        np.testing.assert_array_equal(da, db)  # geometry untouched
        differs += int(np.abs(ca.astype(int) - cb.astype(int)).mean() > 3)
    assert differs >= 4


def test_furniture_changes_only_boxes_and_keeps_what_stayed(base: World) -> None:
    w = changed(furniture=1.0)
    t = w.change_truth.furniture
    assert t["moved"] and t["removed"] and t["added"]
    assert _walls(w) == _walls(base) and w.posters == base.posters and w.lighting is None and w.people is None
    kept = w.box_source >= 0
    assert int((~kept).sum()) == len(t["added"]) and int(kept.sum()) == len(base.boxes) - len(t["removed"])
    moved = {m["box"] for m in t["moved"]}
    for k, src in enumerate(w.box_source):
        if src < 0:
            assert w.box_kinds[k] in ("bin", "plant", "stool", "crate")
            continue
        assert w.box_kinds[k] == base.box_kinds[src] != "pillar" or src not in moved
        if src not in moved:
            np.testing.assert_array_equal(w.boxes[k], base.boxes[src])
        else:
            np.testing.assert_allclose(w.boxes[k, 4], base.boxes[src, 4])
    # a box that stayed (moved or not) keeps its texture columns
    tb, tw = baked_textures(base), baked_textures(w)
    n_walls = len(_walls(base))
    k = int(np.nonzero(kept)[0][-1])
    src = int(w.box_source[k])
    fa, fb = n_walls + 4 * src, n_walls + 4 * k
    wa = int(tb.face_offset[fa + 1] - tb.face_offset[fa])
    np.testing.assert_array_equal(tb.atlas[0][:, int(tb.face_offset[fa]):int(tb.face_offset[fa]) + wa],
                                  tw.atlas[0][:, int(tw.face_offset[fb]):int(tw.face_offset[fb]) + wa])
    # walls look the same; goal spots stay free
    np.testing.assert_array_equal(tb.atlas[0][:, :int(tb.face_offset[n_walls])],
                                  tw.atlas[0][:, :int(tw.face_offset[n_walls])])
    for T in w.goal_places.values():
        assert w.is_free(T[:2, 3], 0.3)


def test_furniture_level_grades_the_change(base: World) -> None:
    def count(level: float) -> int:
        t = changed(furniture=level).change_truth.furniture
        return sum(len(v) for v in t.values())
    assert count(0.1) < count(1.0)


def test_pictures_change_only_pictures(base: World) -> None:
    w = changed(pictures=1.0)
    assert w.faces == base.faces and w.lighting is None
    np.testing.assert_array_equal(w.boxes, base.boxes)
    replaced = {p["index"] for p in w.change_truth.pictures}
    assert replaced
    kinds = set()
    for i, (a, b) in enumerate(zip(base.posters, w.posters, strict=True)):
        assert (a.face, a.s0, a.z0, a.width, a.height, a.kind, a.text) == (b.face, b.s0, b.z0, b.width, b.height,
                                                                           b.kind, b.text)
        assert (a.key != b.key) == (i in replaced)
        if i in replaced:
            kinds.add(a.kind)
            assert a.kind in ("photo", "poster", "print", "notice")
    assert "notice" in kinds


def test_doors_add_leaves_and_keep_the_building_connected() -> None:
    spec = dataclasses.replace(SPEC, rows=2, cols=2, extra_door_prob=1.0)  # loops: doors that can close
    base = World(spec)
    w = World(dataclasses.replace(spec, change=WorldChangeParams(seed=5, doors=1.0)))
    leaves = w.change_truth.doors
    assert len(leaves) <= len(base.doors) and {lf["state"] for lf in leaves} == {"open", "closed"}
    assert _walls(w) == _walls(base) and w.posters == base.posters
    n = len(base.boxes)
    np.testing.assert_array_equal(w.boxes[:n], base.boxes)
    assert w.box_kinds[n:] == ["door"] * len(leaves)
    closed = {lf["door"] for lf in leaves if lf["state"] == "closed"}
    assert closed == w.closed_doors
    open_pairs = [d[:2] for i, d in enumerate(w.doors) if i not in closed]
    seen, todo = {min(w.regions)}, [min(w.regions)]
    while todo:
        r = todo.pop()
        for a, b in open_pairs:
            for x, y in ((a, b), (b, a)):
                if x == r and y not in seen:
                    seen.add(y)
                    todo.append(y)
    assert seen == set(w.regions)
    for i, d in enumerate(w.doors):  # a closed leaf blocks its doorway, an open one leaves it its full width
        mid = np.array([(d[2] + d[4]) / 2, (d[3] + d[5]) / 2])
        assert w.is_free(mid, 0.1) == (i not in closed)
        if i not in closed:
            assert w.clearance(mid)[0] >= base.clearance(mid)[0] - 1e-9


def test_people_occlude_with_depth_and_change_nothing_else(base: World) -> None:
    w = changed(people=2)
    assert w.faces == base.faces and w.posters == base.posters
    np.testing.assert_array_equal(baked_textures(w).atlas[0], baked_textures(base).atlas[0])
    nearer = 0
    for t_ns in (int(1.5e9), int(3.0e9), int(9.0e9)):
        for (ca, da), (cb, db) in zip(_renders(base, t_ns), _renders(w, t_ns), strict=True):
            both = np.isfinite(da) & np.isfinite(db)
            assert np.all(db[both] <= da[both] + 1e-6)  # people only ever stand in front
            hit = both & (db < da - 1e-3)
            nearer += int(hit.sum())
            assert np.array_equal(ca[~hit], cb[~hit])
    assert nearer > 0


def test_axes_draw_from_their_own_streams() -> None:
    alone = changed(furniture=0.5).change_truth.furniture
    mixed = changed(furniture=0.5, pictures=0.5, lighting=0.5).change_truth.furniture
    assert alone == mixed


def test_world_file_change_block(tmp_path: Path) -> None:
    src = (Path(__file__).resolve().parents[2] / "config" / "worlds" / "office.yaml").read_text()
    p = tmp_path / "w.yaml"
    p.write_text(src + "change:\n  furniture: 0.3\n  people: 2\n")
    assert load_world_spec(p).change == WorldChangeParams(furniture=0.3, people=2)
    p.write_text(src + "change:\n  furniture: 1.5\n")
    with pytest.raises(ConfigError, match=r"change\.furniture"):
        load_world_spec(p)
    p.write_text(src + "change:\n  windows: 1\n")
    with pytest.raises(ConfigError, match=r"change\.windows"):
        load_world_spec(p)


def test_parse_change_and_the_months_later_mix() -> None:
    assert parse_change(["months_later"]) == MIXES["months_later"]
    m = parse_change(["months_later", "people=0", "seed=4"])
    assert (m.people, m.seed, m.furniture) == (0, 4, 0.3)
    for bad in ("windows=1", "furniture=1.5", "furniture=x", "people=1.5", "someday", "lighting=nan"):
        with pytest.raises(ChangeSpecError):
            parse_change([bad])


@pytest.mark.parametrize("bad", ["windows=1", "furniture=2", "people=-1", "later"])
def test_cli_rejects_a_bad_change_with_exit_2(tmp_path: Path, bad: str) -> None:
    assert main(["sim", "record", "office", "-o", str(tmp_path / "r.mcap"), "--change", bad]) == 2
    assert not (tmp_path / "r.mcap").exists()


def test_cli_records_a_changed_building_with_its_ground_truth(tmp_path: Path) -> None:
    out = tmp_path / "r.mcap"
    assert main(["sim", "record", "office", "-o", str(out), "--duration", "0.3", "--change", "months_later",
                 "--set", "sim.width=64", "--set", "sim.height=48", "--json", str(tmp_path / "s.json")]) == 0
    truth = json.loads(out.with_suffix(".change.json").read_text())
    assert truth["levels"] == MIXES["months_later"].levels()
    assert truth["people"]["count"] == 2 and truth["furniture"]["moved"] and truth["pictures"]
    plain = tmp_path / "p.mcap"
    assert main(["sim", "record", "office", "-o", str(plain), "--duration", "0.3", "--set", "sim.width=64",
                 "--set", "sim.height=48"]) == 0
    assert not plain.with_suffix(".change.json").exists()
