"""The navigation diagnosis's records and its refusal of a bad change."""

from __future__ import annotations

import numpy as np
import pytest

from litevloc.experiments.change_nav import GOAL_KEYS, goal_rows, main
from litevloc.runtime.tools.sim_driver import GoalRecord
from litevloc.runtime.tools.sim_navigation import NavRun


def test_goal_rows_say_how_each_goal_ended() -> None:
    goals = [GoalRecord("room_01", "reached", "within 0.5 m", time_s=40.0, timeout_s=120.0, shortest_path_m=9.1,
                        placed_node=3, placement_error_m=0.05),
             GoalRecord("room_02", "timeout", "timeout: goal 'room_02' cancelled", time_s=120.0, timeout_s=120.0,
                        distance_to_goal_m=7.3, placed_node=8)]
    rows = goal_rows(NavRun("ground-truth", goals, np.zeros((2, 2)), np.zeros((0, 2)), 160.0, 0, 1.0))
    assert [r["outcome"] for r in rows] == ["reached", "timeout"]
    assert all(tuple(r) == GOAL_KEYS for r in rows)
    assert rows[1]["distance_to_goal_m"] == 7.3 and rows[0]["placement_error_m"] == 0.05


def test_a_change_naming_no_axis_exits_2_with_the_axes(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["office", "100", "--change", "flood=1"]) == 2
    err = capsys.readouterr().err
    assert "unknown axis 'flood'" in err and "people" in err
