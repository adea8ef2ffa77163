"""`litevloc demo`'s results table from a `sim navigate --json` summary."""

from __future__ import annotations

from typing import Any

from litevloc.cli.demo import result_rows


def _nav(reached: int, ratios: dict[str, Any]) -> dict[str, Any]:
    run = {"goals_reached": reached, "goals_total": 5, "time_s": 12.0, "path_length_m": 3.5, "collisions": 0}
    return {**run, "baseline": dict(run), "ratios": ratios, "localization_error_m": None, "runtime": {}}


def test_a_run_where_no_goal_was_reached_by_both_prints_no_ratio() -> None:
    rows = dict(result_rows(_nav(0, {"path_length": None, "time": None})))
    assert rows["goals reached (LiteVLoc)"].startswith("0/5 in 12 s")
    assert rows["LiteVLoc / baseline"] == "no goal reached by both: no ratio"


def test_ratios_are_printed_when_both_reached_a_goal() -> None:
    rows = dict(result_rows(_nav(4, {"path_length": 1.004, "time": 0.98})))
    assert rows["LiteVLoc / baseline"] == "path x1.00, time x0.98"
