"""Integration: a short closed loop in the office (small map, one goal), and `litevloc goal send`."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from litevloc.cli.main import main


@pytest.fixture(scope="module")
def small_map(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Map of the first 12 s of the office mapping pass (the start room)."""
    from litevloc.runtime.tools.world_navigation import ensure_map

    return ensure_map("office", tmp_path_factory.mktemp("nav"), "default", map_duration=12.0)


def test_closed_loop_reaches_a_goal_with_litevloc(small_map: Path, tmp_path: Path) -> None:
    from litevloc.base.params.sim_navigation import NavParams
    from litevloc.config import load_config
    from litevloc.runtime.tools.sim_navigation import render_goals, run_navigation
    from litevloc.sim.world import load_world

    cfg = load_config("default")
    world = load_world("office")
    goal = render_goals(world, cfg, ["room_00"])
    start = world.goal_places["room_00"].copy()
    start[:2, :2] = -start[:2, :2]  # facing away from the goal view ...
    for back in (1.5, 1.2, 0.9):  # ... and a step further from it
        xy = start[:2, 3] + back * start[:2, 0]
        if world.is_free(xy, 0.45):
            start[:2, 3] = xy
            break
    rrd = tmp_path / "nav.rrd"  # the live view saved (issue 17): map, poses, VLoc, planner path
    run = run_navigation(world, cfg, small_map, goal, start, "litevloc", NavParams(goal_timeout_s=40.0),
                         view_save=rrd)
    s = run.summary()
    assert s["goals_reached"] == 1, s["goals"]
    assert s["goals"][0]["placed_node"] is not None and s["goals"][0]["placement_error_m"] is not None  # recorded
    assert s["runtime"]["vloc_accepted"] >= 1 and s["planner"]["poses_in"] > 10
    assert s["localization_error_m"]["median"] < 0.2
    assert s["collisions"] == 0 and s["collision_xy"] == []  # where each bump happened (none here)
    from rerun.chunk import RrdReader

    rows: dict[str, int] = {}
    for chunk in RrdReader(rrd).store().stream():
        rows[str(chunk.entity_path)] = rows.get(str(chunk.entity_path), 0) + chunk.num_rows
    for path in ("/world/fused", "/world/vloc/camera", "/world/plan/path", "/world/plan/subgoal", "/status/planner",
                 "/images/matches", "/images/matches/lines"):
        assert rows.get(path, 0) > 0, (path, sorted(rows))


def test_a_run_that_never_localizes_ends_with_the_reason(small_map: Path) -> None:
    """Started where the map (the start room only) sees nothing, the robot looks around (a full
    turn, then a move to open space, `sim/search.py`); after a goal's time without any pose
    the run ends and every goal fails as never localized, the reason counting the moves."""
    from litevloc.base.params.sim_navigation import NavParams
    from litevloc.config import load_config
    from litevloc.runtime.tools.sim_navigation import render_goals, run_navigation
    from litevloc.sim.world import load_world

    cfg = load_config("default")
    world = load_world("office")
    far = sorted(world.goal_places)[-1]
    goal = render_goals(world, cfg, ["room_00"])
    run = run_navigation(world, cfg, small_map, goal, world.goal_places[far].copy(), "litevloc",
                         NavParams(goal_timeout_s=20.0))
    s = run.summary()
    assert s["goals_reached"] == 0 and s["runtime"]["fusion_accepted"] == 0, s
    (g,) = s["goals"]
    assert g["outcome"] == "failed" and g["reason"].startswith("never localized"), g
    assert 20.0 <= s["time_s"] < 22.0
    # it turned once in place (~12.6 s at 0.5 rad/s after the first 3 s), then moved
    assert s["first_pose_s"] is None and s["search_legs"] >= 1 and f"{s['search_legs']} moves" in g["reason"]
    assert s["path_length_m"] > 0.5 and s["collisions"] == 0


def test_cli_goal_send_without_planner_reports_no_answer(tmp_path: Path) -> None:
    import cv2

    from tests.runtime.zenoh_helpers import free_port

    img = tmp_path / "g.jpg"
    cv2.imwrite(str(img), np.zeros((32, 32, 3), np.uint8))
    ep = f"tcp/127.0.0.1:{free_port()}"
    # nobody listens there: a clear connection error (exit 2), not a hang
    assert main(["goal", "send", str(img), "--connect", ep, "--wait", "0.5"]) == 2
    assert main(["goal", "send", str(tmp_path / "missing.jpg")]) == 2
    _ = json


def test_map_from_the_simulator_reports_how_its_keyframes_were_chosen(small_map: Path, tmp_path: Path) -> None:
    """ensure_map builds straight from the simulator; the map carries coverage, budget and build time."""
    from litevloc.runtime.tools.world_navigation import map_summary

    s = map_summary(small_map)
    assert s["keyframes"] >= 3 and s["coverage"] is not None and s["coverage"] >= 0.95
    assert s["budget"] == "None" and not s["budget_bound"]
    assert s["bytes"] > 10_000 and s["build_seconds"] is not None and s["build_seconds"] > 0
    assert not (small_map.parent / "map.mcap").exists()  # no recording round trip
    # a simulator source takes no --frames (a user error, exit 2)
    assert main(["map", "build", "sim:office?pass=map&duration=2", "-o", str(tmp_path / "m"), "--frames", "0:5"]) == 2


def test_driver_status_callback_updates_state_and_feeds_the_view() -> None:
    """The planner-status callback keeps the driver's status and events under its lock and
    notifies waiters, with or without the live view's hook (a regression: the hook once
    swallowed the status update when the view was off)."""
    import threading
    from types import SimpleNamespace

    from litevloc.hw import ros_msgs
    from litevloc.runtime.tools.sim_driver import SimDriver

    def sample(st: dict) -> SimpleNamespace:
        msg = ros_msgs.typestore().types[ros_msgs.STRING](data=json.dumps(st))
        data = ros_msgs.serialize(msg, ros_msgs.STRING)
        return SimpleNamespace(payload=SimpleNamespace(to_bytes=lambda: data))

    seen: list[dict] = []
    for hook in (None, seen.append):
        d = SimDriver.__new__(SimDriver)
        d.cond, d.status, d.events, d.on_plan = threading.Condition(), {}, [], hook
        d._on_status(sample({"seq": 1, "state": "navigating"}))
        d._on_status(sample({"seq": 2, "state": "reached"}))
        assert d.status["seq"] == 2 and [e["seq"] for e in d.events] == [1, 2]
    assert [s["seq"] for s in seen] == [1, 2]


def test_ensure_map_passes_build_overrides_and_reuses_a_built_map(tmp_path: Path,
                                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    """`ensure_map(..., overrides=...)` builds with each KEY=VALUE applied to the configuration
    (the density benchmark caps the keyframe budget this way) and builds nothing when the map exists."""
    import litevloc.runtime.tools.world_navigation as world_navigation
    from litevloc.config.schema import LiteVLocConfig
    from litevloc.runtime.tools.map_building import MapBuildRequest
    from litevloc.runtime.tools.world_navigation import ensure_map

    calls: list[tuple[MapBuildRequest, LiteVLocConfig]] = []

    def fake_build(req: MapBuildRequest, cfg: LiteVLocConfig) -> dict[str, object]:
        calls.append((req, cfg))
        out = req.output
        out.mkdir(parents=True)
        (out / "manifest.json").write_text("{}")
        return {"nodes": 0}

    monkeypatch.setattr(world_navigation, "build_map", fake_build)
    got = ensure_map("office", tmp_path / "m", "default", overrides=["mapping.keyframes.budget=17"])
    assert got == tmp_path / "m" / "map" and len(calls) == 1
    req, cfg = calls[0]
    assert str(req.src).startswith("sim:office?") and req.config == "default"
    assert cfg.mapping.keyframes.budget == 17
    assert json.loads((tmp_path / "m" / "map.json").read_text()) == {"nodes": 0}
    assert ensure_map("office", tmp_path / "m", "default", overrides=["mapping.keyframes.budget=17"]) == got
    assert len(calls) == 1  # cached


def test_ratios_compare_only_goals_both_modes_reached() -> None:
    from litevloc.runtime.tools.sim_navigation import goal_ratios

    def g(name: str, outcome: str, t: float, p: float) -> dict:
        return {"name": name, "outcome": outcome, "time_s": t, "path_length_m": p}

    lv = [g("a", "reached", 20.0, 10.0), g("b", "failed", 0.0, 0.0), g("c", "timeout", 120.0, 3.0)]
    gt = [g("a", "reached", 10.0, 8.0), g("b", "reached", 30.0, 9.0), g("c", "reached", 5.0, 2.0)]
    assert goal_ratios(lv, gt) == {"goals_compared": 1, "path_length": 1.25, "time": 2.0}
    none = goal_ratios([g("a", "failed", 0.0, 0.0)], gt)
    assert none == {"goals_compared": 0, "path_length": None, "time": None}


def test_sim_navigate_takes_the_loop_settings_from_the_config(tmp_path: Path,
                                                              monkeypatch: pytest.MonkeyPatch) -> None:
    """`sim navigate` runs with the config's `sim_navigation` section (`--set` reaches the local
    planner), its flags on top; nothing else is changed."""
    import litevloc.cli.sim_navigate as cli_nav
    from litevloc.base.params.sim_navigation import NavParams

    seen: list[NavParams] = []

    def fake_navigate(world: str, cfg: object, map_path: Path, goals: object, start: object, modes: object,
                      params: NavParams, *args: object, **kwargs: object) -> dict[str, object]:
        seen.append(params)
        return {"goals": [], "goals_reached": 0, "goals_total": 0, "time_s": 0.0, "path_length_m": 0.0}

    monkeypatch.setattr(cli_nav, "navigate", fake_navigate)
    monkeypatch.setattr(cli_nav, "map_summary", lambda p: dict.fromkeys(("keyframes", "coverage", "bytes",
                                                                          "build_seconds")))
    argv = ["sim", "navigate", "office", "--map", str(tmp_path), "--out-dir", str(tmp_path), "--localization",
            "litevloc", "--set", "sim_navigation.local.max_speed=0.4", "--set", "sim_navigation.seed=3"]
    assert main([*argv, "--vloc-hz", "2"]) == 0
    assert main(argv) == 0
    assert seen[0] == NavParams(vloc_hz=2.0, seed=3, local=dataclasses.replace(NavParams().local, max_speed=0.4))
    assert seen[1].vloc_hz == NavParams().vloc_hz and seen[1].local.max_speed == 0.4 and seen[1].seed == 3


def test_a_far_goal_gets_time_for_its_path() -> None:
    """A goal's budget grows with its shortest free path where that path is long (a far room of
    the 15-room floor), and stays `goal_timeout_s` for a near one."""
    from litevloc.base.params.sim_navigation import NavParams
    from litevloc.runtime.tools.sim_driver import goal_budget
    from litevloc.sim.world import load_world

    world = load_world("floor", seed=10)
    p = NavParams(goal_timeout_s=120.0, goal_timeout_s_per_m=4.0)
    start, near, far = (world.goal_places[r][:2, 3] for r in ("room_00", "room_01", "room_10"))
    t_near, d_near = goal_budget(world, start, near, 0.3, p)
    t_far, d_far = goal_budget(world, start, far, 0.3, p)
    assert d_near is not None and d_far is not None and d_far > max(d_near, 30.0), (d_near, d_far)
    assert d_far >= float(np.linalg.norm(far - start))  # a path, not the straight line through walls
    assert t_far == pytest.approx(4.0 * d_far) and t_near == max(120.0, 4.0 * d_near)
    assert goal_budget(world, start, far, 0.3, dataclasses.replace(p, goal_timeout_s_per_m=0.0)) == (120.0, None)


def test_concurrent_baseline(small_map: Path, tmp_path: Path) -> None:
    """`sim navigate --concurrent-baseline` (the demo's): the ground-truth run in a second
    process comes back as the baseline beside the LiteVLoc run (goal time 10 s: the baseline
    reaches the goal in about 8 s; the LiteVLoc run, three VLoc queries at 0.3 Hz to keep the
    test short, need not)."""
    import os

    from litevloc.base.params.sim_navigation import NavParams
    from litevloc.config import load_config
    from litevloc.runtime.tools.world_navigation import navigate

    res = navigate("office", load_config("default"), small_map, ["room_00"], "room_00", ["litevloc", "ground-truth"],
                   NavParams(goal_timeout_s=10.0, vloc_hz=0.3), png=tmp_path / "nav.png", concurrent_baseline=True)
    assert res["mode"] == "sequential" and res["goals_total"] == 1 and res["pid"] == os.getpid()
    b = res["baseline"]
    assert b["mode"] == "ground-truth pose" and b["goals_reached"] == 1, b["goals"]
    assert b["pid"] != os.getpid()
    assert (tmp_path / "nav.png").is_file()
