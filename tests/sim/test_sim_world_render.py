"""Worlds load strictly from YAML, are connected and deterministic; depth is metric."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from litevloc.base.geometry import PinholeIntrinsics
from litevloc.base.loader import ConfigError
from litevloc.sim.elements import pose2d
from litevloc.sim.render import Renderer, RenderError
from litevloc.sim.simulator import SimParams, camera_pose
from litevloc.sim.spec import WorldSpec, world_names
from litevloc.sim.trajectory import plan_path
from litevloc.sim.world import load_world


@pytest.fixture(scope="module")
def office():
    return load_world("office")


def test_shipped_worlds_and_strict_loading(tmp_path: Path) -> None:
    assert {"office", "floor", "loop"} <= set(world_names())
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: x\nrooms: 3\n")
    with pytest.raises(ConfigError, match="rooms"):
        load_world(bad)
    bad.write_text("name: x\nlayout: loop\n")
    with pytest.raises(ConfigError, match="corridor_width"):
        load_world(bad)
    with pytest.raises(ConfigError, match="unknown world"):
        load_world("no_such_world")


def test_world_is_deterministic_and_connected(office) -> None:
    again = load_world("office")
    assert np.array_equal(office.labels, again.labels)
    assert np.array_equal(office.boxes, again.boxes)
    assert office.faces == again.faces
    other = load_world("office", seed=5)
    assert not np.array_equal(office.boxes, other.boxes) or office.doors != other.doors
    # every room is reachable from room 0 through doors, with the robot's radius
    rooms = [k for k, r in office.regions.items() if r.kind == "room"]
    start = office.room_centre(rooms[0])
    for k in rooms[1:]:
        path = plan_path(office, start, office.room_centre(k), 0.3)
        assert all(office.is_free(p, 0.3) for p in path[::2])
    assert len(office.goal_places) == len(rooms)


def test_is_free_against_walls_and_boxes(office) -> None:
    x0, y0, _x1, _y1 = office.bounds
    assert not office.is_free(np.array([x0 - 1.0, y0 - 1.0]), 0.1)  # outside
    f = next(f for f in office.faces if f.kind == "wall" and f.axis == 0 and f.hi - f.lo > 2)
    mid = (f.lo + f.hi) / 2
    assert not office.is_free(np.array([f.c + 0.1 * f.normal, mid]), 0.3)
    b = office.boxes[0]
    assert not office.is_free(np.array([(b[0] + b[2]) / 2, (b[1] + b[3]) / 2]), 0.1)
    c = office.room_centre(1)
    assert office.is_free(c, 0.3)


def test_render_depth_is_metric(office) -> None:
    """A level camera facing a wall at a known distance sees that distance at the centre pixel."""
    K = PinholeIntrinsics(50.0, 50.0, 31.5, 23.5, 64, 48)
    ren = Renderer(office)
    _name, T_base = sorted(office.goal_places.items())[0]
    params = SimParams(camera_tilt_deg=0.0, camera_forward=0.0)
    T_cam = camera_pose(T_base, 0.0, 0.0, params)
    color, depth = ren.render(T_cam, K)
    assert color.shape == (48, 64, 3) and color.dtype == np.uint8
    assert depth.shape == (48, 64) and depth.dtype == np.float32
    # goal places stand in front of a poster on a wall: cast the same ray through the plan
    fwd = T_base[:2, 0]
    p = T_base[:2, 3]
    hits = []
    for f in office.faces:
        if f.kind != "wall":
            continue
        a = f.axis
        if abs(fwd[a]) < 1e-9:
            continue
        t = (f.c - p[a]) / fwd[a]
        q = p[1 - a] + t * fwd[1 - a]
        if t > 0 and f.lo <= q <= f.hi:
            hits.append(t)
    centre = depth[23:25, 31:33]
    assert np.allclose(centre, min(hits), atol=0.03)  # 2.5 m: goal places stand 2.5 m off a wall
    # tilted camera: floor pixels at the bottom are closer than at the horizon
    color_t, depth_t = ren.render(camera_pose(T_base, 0.0, 0.0, SimParams(camera_tilt_deg=10.0)), K)
    assert np.all(np.isfinite(depth_t))
    assert depth_t[-1].mean() < depth_t[24].mean()
    assert color_t.std() > 10  # textured, not a flat image
    # stereo: the right camera (+x) sees a wall point f * b / z pixels further left
    left, right, depth_l = ren.render_stereo(T_cam, K, 0.2)
    assert left.shape == right.shape == (48, 64, 3) and depth_l.shape == (48, 64)
    z = float(depth_l[10, 40])
    shift = 50.0 * 0.2 / z
    assert np.isfinite(z) and shift > 1.0
    T_up = T_cam.copy()
    T_up[:3, :3] = T_up[:3, :3] @ np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]])
    with pytest.raises(RenderError):
        ren.render(T_up, K)


def test_render_is_deterministic(office) -> None:
    K = PinholeIntrinsics(50.0, 50.0, 31.5, 23.5, 64, 48)
    T = camera_pose(pose2d(*office.room_centre(2), 0.7), 0.3, 0.5, SimParams())
    c1, d1 = Renderer(office).render(T, K)
    c2, d2 = Renderer(load_world("office")).render(T, K)
    assert c1.tobytes() == c2.tobytes()
    assert d1.tobytes() == d2.tobytes()


def test_spec_validation() -> None:
    with pytest.raises(ValueError, match="room_size"):
        WorldSpec(name="x", room_size=(1.0, 4.0))
    with pytest.raises(ValueError, match="door_width"):
        WorldSpec(name="x", door_width=0.2)


@pytest.mark.parametrize("name", ["office", "floor", "loop"])
def test_shipped_worlds_connected_through_doors(name: str) -> None:
    w = load_world(name)
    graph: dict[int, set[int]] = {k: set() for k in w.regions}
    for a, b, *_ in w.doors:
        graph[a].add(b)
        graph[b].add(a)
    seen, todo = set(), [next(iter(w.regions))]
    while todo:
        k = todo.pop()
        if k not in seen:
            seen.add(k)
            todo += graph[k]
    assert seen == set(w.regions)
    # doors are wide enough for the robot: the door centre is free with a 0.3 m radius
    for _, _, x0, y0, x1, y1 in w.doors:
        assert w.is_free(np.array([(x0 + x1) / 2, (y0 + y1) / 2]), 0.3)


def test_loop_pass_laps_the_ring_corridor(office) -> None:
    from litevloc.sim.trajectory import PlanningError, pass_tasks

    loop = load_world("loop")
    start, tasks = pass_tasks(loop, "loop", 0, SimParams())
    length = sum(
        float(np.linalg.norm(np.diff(t.path, axis=0), axis=1).sum())
        for t in tasks
        if t.path is not None
    )
    assert 190 <= length <= 215  # ~192 m centre line + 10 m overlap past the start
    assert np.allclose(tasks[-2].path[-1], start[:2, 3])  # back at the start before the overlap
    with pytest.raises(PlanningError, match="layout 'loop'"):
        pass_tasks(office, "loop", 0, SimParams())
    # the query lap: the other way round, in another lane
    start_b, tasks_b = pass_tasks(loop, "loop-back", 0, SimParams())
    length_b = sum(float(np.linalg.norm(np.diff(t.path, axis=0), axis=1).sum()) for t in tasks_b if t.path is not None)
    assert 185 <= length_b <= 215
    assert np.allclose(start_b[:2, 0], [-1.0, 0.0])  # heading -x where the map lap heads +x
    assert abs(start_b[1, 3] - start[1, 3]) > 0.25  # another lane
    with pytest.raises(PlanningError, match="layout 'loop'"):
        pass_tasks(office, "loop-back", 0, SimParams())
    start_c, tasks_c = pass_tasks(loop, "loop-lane", 0, SimParams())  # the same way, in the other lane
    assert np.allclose(start_c[:2, 0], [1.0, 0.0]) and abs(start_c[1, 3] - start[1, 3]) > 0.25
    length_c = sum(float(np.linalg.norm(np.diff(t.path, axis=0), axis=1).sum()) for t in tasks_c if t.path is not None)
    assert 185 <= length_c <= 215


def test_depth_only_render_equals_full_render_depth(office) -> None:
    """`render_depth` skips texturing but must give the very depth of `render` (level and tilted)."""
    K = PinholeIntrinsics(50.0, 50.0, 31.5, 23.5, 64, 48)
    ren = Renderer(office)
    for k, (_name, T_base) in enumerate(sorted(office.goal_places.items())[:3]):
        params = SimParams(camera_tilt_deg=[0.0, 8.0, -5.0][k])
        T_cam = camera_pose(T_base, 0.3 * k, 0.4 * k, params)
        _color, depth = ren.render(T_cam, K)
        d2 = ren.render_depth(T_cam, K)
        assert np.isfinite(depth).mean() > 0.9
        np.testing.assert_array_equal(depth, d2)
