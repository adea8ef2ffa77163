"""Planner service logic (messages fed directly) and one round trip over Zenoh on loopback."""

from __future__ import annotations

import dataclasses
import json
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from litevloc.base.params.navigation import TrackerParams
from litevloc.config.schema import PlannerConfig, ZenohConfig
from litevloc.hw import ros_msgs
from litevloc.pipelines.navigation.candidates import GoalResult
from litevloc.pipelines.topomap.types import OccupancyGrid
from litevloc.runtime.planner.core import GoalPlanner, PlannerStatus, Subgoal
from litevloc.runtime.planner.node import KEYS, PlannerService
from tests.pipelines.navigation.test_planner import grid_map
from tests.runtime.zenoh_helpers import free_port

T_BC = np.eye(4)  # camera at the base: node base positions = node camera positions


def planner(locate_nodes: dict[int, int | None], goal_places: dict[int, np.ndarray] | None = None,
            cells: np.ndarray | None = None, **tracker: float) -> GoalPlanner:
    """Nodes 0..3 on a line 1 m apart (x = 0..3 m); goal image k (first byte) -> node (and,
    in `goal_places`, the goal camera's metric pose in the map); `cells`: the grid's (80, 80)
    cells (default all free)."""
    m = grid_map([(0, 1, 1.0), (1, 2, 1.0), (2, 3, 1.0)], 4)
    # z up, as the service's level poses assume: 8 x 8 m of floor around the nodes, 0.1 m cells
    free = np.full((80, 80), OccupancyGrid.FREE, np.uint8) if cells is None else cells
    m = dataclasses.replace(m, grid=OccupancyGrid(free, np.array([-2.0, -4.0]), 0.1, np.array([0, 0, 1.0]),
                                                  np.eye(3)[:2]))

    def locate(rgb: np.ndarray) -> GoalResult:
        k = int(rgb[0, 0, 0])
        node = locate_nodes[k]
        return GoalResult(node, 50 if node is not None else 3, "ok" if node is not None else
                          "goal image matches no map place (best 3 inliers < 40)", (),
                          (goal_places or {}).get(k), 80)

    cfg = PlannerConfig(tracker=TrackerParams(reach_m=0.3, stray_m=1.5, clearance_m=0.0, **tracker))
    return GoalPlanner(m, locate, cfg, T_BC)


def img(k: int) -> np.ndarray:
    a = np.zeros((32, 32, 3), np.uint8)
    a[0, 0, 0] = k
    return a


def pose(x: float) -> np.ndarray:
    T = np.eye(4)
    T[0, 3] = x
    T[2, 3] = float(grid_map([], 1).positions[0, 2])  # same height as the nodes
    return T


def kinds(outs: list) -> list[str]:
    return ["subgoal" if isinstance(o, Subgoal) else f"status:{o.state}" for o in outs]


def test_goal_matching_no_place_fails_and_publishes_no_subgoal() -> None:
    p = planner({1: None})
    p.on_pose(1, pose(0.0))
    outs = p.add_goal("nowhere", img(1))
    assert kinds(outs) == ["status:failed"]
    assert "matches no map place" in outs[0].reason and outs[0].goal == "nowhere"
    assert kinds(p.on_pose(2, pose(0.1))) == []  # nothing to do: no subgoal ever
    assert not p.busy


def test_sequence_of_goals_subgoals_advance_and_reach() -> None:
    p = planner({1: 2, 2: 0})
    assert kinds(p.add_goal("a", img(1))) == ["status:idle"]  # no pose yet: queued
    outs = p.on_pose(10, pose(0.0))
    assert kinds(outs) == ["status:planned", "subgoal"]
    assert outs[0].path == (0, 1, 2) and outs[0].goal == "a"
    assert kinds(p.add_goal("b", img(2))) == ["status:planned"]  # queued behind a
    assert p.status.queued == 1
    outs = p.on_pose(11, pose(0.05))  # node 0 reached -> subgoal node 1, in the robot frame too
    assert kinds(outs) == ["status:planned", "subgoal"]
    sub = outs[1]
    assert sub.node == 1 and sub.t_ns == 11 and np.isclose(sub.T_base_subgoal[0, 3], 0.95)
    assert kinds(p.on_pose(12, pose(0.5))) == ["subgoal"]  # every pose: a subgoal (period 0)
    outs = p.on_pose(13, pose(1.0))
    outs += p.on_pose(14, pose(2.0))
    ks = kinds(outs)
    assert "status:reached" in ks and ks[-2:] == ["status:planned", "subgoal"]  # goal b starts at once
    reached = next(o for o in outs if isinstance(o, PlannerStatus) and o.state == "reached")
    assert reached.goal == "a" and reached.busy
    assert p.active == "b" and p.status.path[-1] == 0
    outs = p.on_pose(15, pose(0.0))
    outs += p.on_pose(16, pose(0.0))
    st = [o for o in outs if isinstance(o, PlannerStatus)][-1]
    assert st.state == "reached" and st.goal == "b" and not st.busy and st.pose_t_ns in (15, 16)


def test_final_approach_drives_on_to_the_goal_images_place() -> None:
    place = pose(2.0)
    place[1, 3] = 0.8  # the goal image was taken 0.8 m beside node 2
    p = planner({1: 2, 2: 1}, goal_places={1: place})
    outs = p.add_goal("beside", img(1))  # no pose yet: queued, with where its place is
    assert "its place 0.80 m from the node (80 PnP inliers; 0.80 m on the grid)" in outs[0].reason
    for t, x in enumerate((0.0, 0.05, 1.0)):
        p.on_pose(t, pose(x))
    outs = p.on_pose(3, pose(2.0))  # at the goal node: not reached yet, on to the place
    assert kinds(outs) == ["status:planned", "subgoal"] and "goal image's place 0.80 m away" in outs[0].reason
    sub = outs[1]
    np.testing.assert_allclose(sub.T_map_subgoal[:3, 3], place[:3, 3], atol=1e-9)
    np.testing.assert_allclose(sub.T_base_subgoal[:3, 3], [0.0, 0.8, 0.0], atol=1e-9)
    beside = pose(2.0)
    beside[1, 3] = 0.4  # 0.4 m short of the place (> reach 0.3 m)
    assert kinds(p.on_pose(4, beside)) == ["subgoal"]
    beside[1, 3] = 0.6
    outs = p.on_pose(5, beside)
    assert kinds(outs) == ["status:reached"] and "goal image's place" in outs[0].reason
    # a goal without a metric place (or with final_approach off) stops at its node as before
    outs = p.add_goal("node only", img(2))
    outs += p.on_pose(6, pose(2.0))
    outs += p.on_pose(7, pose(1.0))
    assert "status:reached" in kinds(outs) and "goal node 1" in outs[-1].reason
    off = planner({1: 2}, goal_places={1: place}, final_approach=False)
    off.add_goal("x", img(1))
    for t, x in enumerate((0.0, 0.05, 1.0)):
        off.on_pose(t, pose(x))
    assert kinds(off.on_pose(3, pose(2.0))) == ["status:reached"]


def wall(p: GoalPlanner, y: float, x0: float, x1: float) -> None:
    """An occupied wall 0.1 m thick at y (m) from x0 to x1 on the planner map's grid (origin (-2, -4), 0.1 m)."""
    i, j0, j1 = round((y + 4.0) / 0.1), round((x0 + 2.0) / 0.1), round((x1 + 2.0) / 0.1)
    p.map.grid.cells[i, max(j0, 0):j1] = OccupancyGrid.OCCUPIED


def test_a_goal_place_behind_a_wall_from_its_node_is_refused_not_driven_to() -> None:
    place = pose(2.0)
    place[1, 3] = 0.8
    p = planner({1: 2}, goal_places={1: place})
    wall(p, 0.4, -2.0, 6.0)  # the whole floor split between node 2 (y = 0) and the place (y = 0.8)
    p.on_pose(0, pose(0.0))
    outs = p.add_goal("walled", img(1))
    assert kinds(outs) == ["status:failed"]
    reason = outs[0].reason
    assert "placed at node 2, refused" in reason and "not reachable on the map's grid" in reason
    assert not p.busy and kinds(p.on_pose(1, pose(0.1))) == []


def test_the_final_approach_goes_round_an_obstacle_and_is_reached_only_at_the_place() -> None:
    place = pose(2.0)
    place[1, 3] = 0.8
    p = planner({1: 2}, goal_places={1: place})
    wall(p, 0.4, 1.5, 2.5)  # a bench between node 2 and the place
    p.on_pose(0, pose(0.0))
    assert kinds(p.add_goal("round", img(1))) == ["status:planned", "subgoal"]  # placed and started
    for t, x in enumerate((0.05, 1.0), start=1):
        p.on_pose(t, pose(x))
    outs = p.on_pose(3, pose(2.0))  # at the goal node: on along the grid path, first to a turn beside the bench
    assert kinds(outs) == ["status:planned", "subgoal"] and "legs" in outs[0].reason
    turn = outs[1].T_map_subgoal[:3, 3]
    assert np.linalg.norm(turn[:2] - place[:2, 3]) > 0.5 and abs(turn[0] - 2.0) > 0.5  # beside the bench's end
    legs = outs[1].legs_left
    assert outs[1].final and legs == len(p.approach_left)
    assert legs >= 2
    at_turn = pose(float(turn[0]))
    at_turn[1, 3] = turn[1]
    outs = p.on_pose(4, at_turn)  # the turn reached: the next subgoal is the place, still not reached
    assert kinds(outs) == ["subgoal"] and outs[0].legs_left < legs
    np.testing.assert_allclose(outs[0].T_map_subgoal[:3, 3], p.approach_left[0], atol=1e-9)
    outs = p.on_pose(5, place)
    assert kinds(outs) == ["status:reached"] and "goal image's place" in outs[0].reason


def test_a_subgoal_node_behind_a_wall_is_published_as_the_turns_round_its_end() -> None:
    p = planner({1: 3})
    p.map.grid.cells[:round((0.6 + 4.0) / 0.1), 35] = OccupancyGrid.OCCUPIED  # wall x = 1.5 m, y < 0.6 m
    p.on_pose(0, pose(0.0))
    p.add_goal("behind", img(1))
    p.on_pose(1, pose(0.05))
    outs = p.on_pose(2, pose(1.0))  # node 1 reached: node 2 lies behind the wall
    sub = [o for o in outs if isinstance(o, Subgoal)][-1]
    assert sub.node == 2 and sub.T_map_subgoal[1, 3] > 0.6  # the turn past the wall's end, not the node
    np.testing.assert_allclose(sub.T_base_subgoal[:3, 3], sub.T_map_subgoal[:3, 3] - [1.0, 0.0, 0.0], atol=1e-9)
    at = pose(float(sub.T_map_subgoal[0, 3]))
    at[1, 3] = sub.T_map_subgoal[1, 3]
    subs = [o for o in p.on_pose(3, at) if isinstance(o, Subgoal)]  # that turn reached: the next one at once
    assert subs and subs[-1].node == 2 and not np.allclose(subs[-1].T_map_subgoal[:3, 3], sub.T_map_subgoal[:3, 3])


def test_replan_when_strayed_and_cancel() -> None:
    p = planner({1: 3})
    p.on_pose(1, pose(0.0))
    p.add_goal("far", img(1))
    far = pose(1.0)
    far[1, 3] = 2.5  # 2.5 m off the path
    outs = p.on_pose(2, far)
    assert p.tracker.replans == 1 and "replanned" in outs[0].reason
    outs = p.cancel("current")
    assert kinds(outs) == ["status:failed"] and "cancelled" in outs[0].reason
    assert not p.busy
    assert "unknown cancel" in p.cancel("everything")[0].reason


def test_a_goal_without_progress_fails_with_its_reason_and_the_next_starts() -> None:
    """Blocked 1 m short of node 3 (a door frame): after stall_s of sensor time without coming
    stall_progress_m closer, the goal fails with the reason and the queued one starts; steady
    slow progress never trips it."""
    s = 1_000_000_000
    p = planner({1: 3, 2: 0}, stall_s=10.0)
    p.on_pose(0, pose(0.0))
    p.add_goal("blocked", img(1))
    p.add_goal("next", img(2))
    outs = []
    for k in range(1, 30):
        outs = p.on_pose(k * s, pose(2.0 if k >= 2 else 1.0))  # at x = 2 m from t = 2 s on, no closer
        if any(kind == "status:failed" for kind in kinds(outs)):
            break
    failed = [o for o in outs if isinstance(o, PlannerStatus) and o.state == "failed"]
    assert failed and failed[0].goal == "blocked" and "no progress for 10 s" in failed[0].reason
    assert k == 13  # 10 s after the last progress it saw (the pose at t = 2 s, checked on the next one)
    assert p.active == "next"
    slow = planner({1: 3}, stall_s=10.0)
    slow.on_pose(0, pose(0.0))
    slow.add_goal("slow", img(1))
    for k in range(1, 60):  # 0.05 m/s: 0.25 m every 5 s
        assert "status:failed" not in kinds(slow.on_pose(k * s, pose(0.05 * k)))
    off = planner({1: 3}, stall_s=0.0)
    off.on_pose(0, pose(0.0))
    off.add_goal("patient", img(1))
    assert all("status:failed" not in kinds(off.on_pose(k * s, pose(1.0))) for k in range(1, 200))


def test_a_detour_round_a_wall_is_progress_not_a_stall() -> None:
    """The leg from node 1 to node 2 crosses a wall whose door is 3 m aside: the grid detour
    makes the way left 6 m longer than it was at node 1. A robot driving it at 0.3 m/s comes
    closer along the detour, not to the shortest way left before it: it reaches the goal."""
    s = 1_000_000_000
    wall = np.full((80, 80), OccupancyGrid.FREE, np.uint8)
    wall[:65, 35] = OccupancyGrid.OCCUPIED  # x = 1.5 m, from y = -4 m to 2.5 m: the door is at y 2.5-4 m
    p = planner({1: 3}, cells=wall, stall_s=5.0, leg_detour_m=10.0)
    xy = target = np.array([0.0, 0.0])
    p.on_pose(0, pose(0.0))
    p.add_goal("round", img(1))
    states = []
    for k in range(1, 200):
        T = pose(0.0)
        T[:2, 3] = xy
        outs = p.on_pose(k * s, T)
        states += [o.state for o in outs if isinstance(o, PlannerStatus)]
        if "reached" in states or "failed" in states:
            break
        sub = [o for o in outs if isinstance(o, Subgoal)]
        if sub:  # drive toward the latest subgoal (a node, or a turn of the detour)
            target = np.asarray(sub[-1].T_map_subgoal[:2, 3])
        step = target - xy
        xy = xy + step * min(1.0, 0.3 / max(float(np.linalg.norm(step)), 1e-9))
    assert "reached" in states and "failed" not in states, states


def test_each_placement_is_reported_in_arrival_order_and_the_status_keeps_its_json_keys() -> None:
    p = planner({1: None, 2: 2})
    placed: list = []
    p.on_placed = placed.append
    p.add_goal("nowhere", img(1))
    p.add_goal("there", img(2))
    assert [pl.result.node for pl in placed] == [None, 2] and "matches no map place" in placed[0].result.reason
    status = json.loads(json.dumps(p.status.as_dict()))
    assert set(status) == {"state", "reason", "goal", "goal_node", "subgoal_node", "path", "remaining_m", "queued",
                           "goals_received", "seq", "pose_t_ns", "replans", "busy"}
    assert status["state"] == "idle" and status["path"] == [] and status["goals_received"] == 2


def test_an_unreadable_goal_message_is_counted_and_failed() -> None:
    p = planner({})
    outs = p.reject_goal("g", "bad CDR")
    assert kinds(outs) == ["status:failed"] and outs[0].reason == "goal 'g': undecodable message: bad CDR"
    assert p.status.goals_received == 1


def test_undecodable_goal_bytes_fail_with_reason() -> None:
    p = planner({})
    outs = p.add_goal("junk", b"not an image at all" * 10)
    assert kinds(outs) == ["status:failed"] and "decodable" in outs[0].reason


def test_over_zenoh_goal_status_and_subgoals() -> None:
    """Pose + goal in over Zenoh (loopback, free port), subgoal_base and status out."""
    import cv2

    from litevloc.runtime.planner.goal_client import send_goals
    from litevloc.runtime.transport.bus import Bus

    ep = f"tcp/127.0.0.1:{free_port()}"
    z = ZenohConfig(listen=(ep,))
    zc = dataclasses.replace(z, listen=(f"tcp/127.0.0.1:{free_port()}",), connect=(ep,))
    p = planner({7: 2, 9: None})
    with Bus(z) as bus_p, Bus(zc) as bus_c:
        svc = PlannerService(bus_p, p).start()
        got: list = []
        ev = threading.Event()

        def on_sub(sample) -> None:  # type: ignore[no-untyped-def]
            m = ros_msgs.deserialize(sample.payload.to_bytes(), ros_msgs.POSE_STAMPED)
            got.append((ros_msgs.stamp_ns(m.header), m.header.frame_id, ros_msgs.pose_to_matrix(m.pose)))
            ev.set()

        sub = bus_c.session.declare_subscriber(KEYS["subgoal_base"], on_sub)
        pose_pub = bus_c.publisher(KEYS["pose"], ros_msgs.ODOMETRY)
        time.sleep(0.5)
        pose_pub.put(ros_msgs.odometry_msg(5, pose(0.6), "map", "base_link"))
        _, good = cv2.imencode(".png", img(7)[:, :, ::-1])
        _, bad = cv2.imencode(".png", img(9)[:, :, ::-1])
        st = send_goals(bus_c, [("there", good.tobytes())], wait_s=5.0)
        assert st is not None and st["state"] == "planned" and st["goal"] == "there", st
        assert ev.wait(5.0)
        t, frame, T = got[-1]
        assert frame == "base_link" and t == 5 and np.isclose(T[0, 3], 0.4)  # node 1 at x=1, robot at 0.6
        st = send_goals(bus_c, [("nowhere", bad.tobytes())], wait_s=5.0)
        assert st is not None and st["state"] == "failed" and "matches no map place" in st["reason"]
        sub.undeclare()
        pose_pub.undeclare()
        svc.close()
        assert svc.counters["poses_in"] == 1 and svc.counters["goals_in"] == 2
        assert json.loads(json.dumps(p.status.as_dict()))["goal"] == "nowhere"


def test_planner_config_validation() -> None:
    with pytest.raises(ValueError, match="publish_period_s"):
        PlannerConfig(publish_period_s=-1)
    with pytest.raises(ValueError, match="clearance_m"):
        TrackerParams(clearance_m=-0.1)
    with pytest.raises(ValueError, match="stall_s"):
        TrackerParams(stall_s=-1.0)


def test_planner_section_loads_from_config() -> None:
    from litevloc.base.loader import ConfigError
    from litevloc.config import load_config

    c = load_config("default", ["planner.tracker.reach_m=0.7", "planner.goal.top_k=3"])
    assert c.planner.tracker.reach_m == 0.7 and c.planner.goal.top_k == 3
    with pytest.raises(ConfigError, match=r"planner\.tracker"):
        load_config("default", ["planner.tracker.reach_m=5"])


def test_plan_cli_writes_the_final_status_as_json(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """`litevloc plan --json` ends with the counters and the planner's status object."""
    import litevloc.cli.plan as plan_cli
    import litevloc.runtime.planner.node as node
    from litevloc.cli.main import main

    # patched where `plan` binds it: patching topomap.io would leak into modules first imported meanwhile
    monkeypatch.setattr(plan_cli, "load_map", lambda path: None)
    monkeypatch.setattr(node, "build_planner", lambda cfg, topomap: planner({}))
    out = tmp_path / "plan.json"
    assert main(["plan", "--map", str(tmp_path), "--listen", f"tcp/127.0.0.1:{free_port()}", "--duration", "0.2",
                 "--json", str(out)]) == 0
    got = json.loads(out.read_text())
    assert got["status"]["state"] == "idle" and got["status"]["seq"] >= 1 and got["counters"]["poses_in"] == 0
