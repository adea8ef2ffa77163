"""bench/goal_placement.py's scoring of one placement (`outcome`)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from tests.bench import load_bench


def test_a_placement_is_right_wrong_or_refused_by_its_distance_from_the_truth() -> None:
    b = load_bench("goal_placement")
    T_true = np.eye(4)
    T_true[:3, 3] = [1.0, 2.0, 0.5]
    kf = np.stack([np.eye(4), np.eye(4)])
    kf[1, :3, 3] = [3.0, 2.0, 0.5]  # node 1 stands 2 m from the true place
    topomap = SimpleNamespace(T_map_camera=kf)
    assert b.outcome(SimpleNamespace(node=None, T_map_goal=None), topomap, T_true, 1.5) == ("refused", None)
    near = T_true.copy()
    near[0, 3] += 1.0
    assert b.outcome(SimpleNamespace(node=0, T_map_goal=near), topomap, T_true, 1.5) == ("right", 1.0)
    far = T_true.copy()
    far[1, 3] += 6.0
    assert b.outcome(SimpleNamespace(node=0, T_map_goal=far), topomap, T_true, 1.5) == ("wrong", 6.0)
    # no metric goal pose: the node's keyframe counts, within twice the radius
    assert b.outcome(SimpleNamespace(node=1, T_map_goal=None), topomap, T_true, 1.5) == ("right", 2.0)
    assert b.outcome(SimpleNamespace(node=1, T_map_goal=None), topomap, T_true, 0.9)[0] == "wrong"


def test_counts_tell_the_goal_places_from_the_extra_frames() -> None:
    b = load_bench("goal_placement")
    recs = [{"image": "room_01", "outcome": "right"}, {"image": "room_02", "outcome": "refused"},
            {"image": "frame_17", "outcome": "right"}, {"image": "frame_90", "outcome": "wrong"}]
    assert b.placement_counts(recs) == {"right": 2, "wrong": 1, "refused": 1, "goal_places_right": 1,
                                        "goal_places": 2}
