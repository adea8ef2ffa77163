"""experiments.change.contract: the bench's `cases` and `update_cycles` pooled over buildings."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from litevloc.experiments.change import Case, contract, gl_summary, plot


def _fig(covered: int, accepted: int, wrong: int, reached: int, total: int) -> dict[str, Any]:
    frames = [{"covered": k < covered, "accepted": k < accepted, "error_m": 1.0 if k < wrong else 0.1}
              for k in range(max(covered, accepted) + 1)]
    return {"gl": {"summary": gl_summary(frames)}, "nav": {"goals_reached": reached, "goals_total": total}}


def fake_building(scale: int) -> dict[str, Any]:
    return {"unchanged": _fig(10 * scale, 10 * scale, 0, 4, 4),
            "cases": [{"axis": "furniture", "level": 0.3, "before": _fig(10 * scale, 5 * scale, 1, 2, 4),
                       "after": _fig(10 * scale, 9 * scale, 0, 4, 4)}],
            "cycles": [{"cycle": c, "map_size_ratio": (10 + scale + c) / 10, "nodes": 10 + scale + c,
                        "gl": gl_summary([{"covered": True, "accepted": k < scale} for k in range(2)])}
                       for c in (1, 2)]}


def test_cases_pool_frames_and_goals_over_buildings() -> None:
    res = contract([fake_building(1), fake_building(2), {"building": "x", "error": "boom"}])
    (c,) = res["cases"]
    assert (c["axis"], c["level"]) == ("furniture", 0.3)
    assert c["gl_accepted_of_covered"] == 0.5 and c["wrong_over_0_5m"] == 2
    assert c["gl_accepted_of_covered_unchanged"] == 1.0
    assert (c["goals_reached"], c["goals_total"], c["goals_reached_unchanged"]) == (4, 8, 8)
    a = c["after_update"]
    assert a["gl_accepted_of_covered"] == 0.9 and a["wrong_over_0_5m"] == 0 and a["goals_reached"] == 8
    first, second = res["update_cycles"]
    assert first == {"cycle": 1, "map_size_ratio": 1.25, "map_size_ratio_to_first_update": 1.0,
                     "gl_accepted_of_covered": 0.75}
    assert second["map_size_ratio"] == 1.35  # (13 / 10 + 14 / 10) / 2
    assert second["map_size_ratio_to_first_update"] == round((13 / 12 + 14 / 13) / 2, 4)


def test_a_wrong_pose_counts_covered_or_not() -> None:
    s = gl_summary([{"covered": False, "accepted": True, "error_m": 0.8},
                    {"covered": True, "accepted": True, "error_m": 0.2}, {"covered": True, "accepted": False}])
    assert (s["wrong_over_0_5m"], s["accepted_covered"], s["covered"], s["gl_accepted_of_covered"]) == (1, 1, 2, 0.5)


def test_months_later_case_is_the_fixed_mix() -> None:
    p = Case("months_later", 1.0).params(seed=3)
    assert (p.seed, p.lighting, p.furniture, p.pictures, p.people, p.doors) == (3, 0.5, 0.3, 0.3, 2, 0.0)
    assert Case("people", 2.0).params().people == 2


def test_the_plot_has_a_panel_per_axis_and_one_for_the_update_cycles(tmp_path: Path) -> None:
    res = contract([fake_building(1), fake_building(2)])
    assert plot(res, tmp_path / "c.png").stat().st_size > 0
    assert plot({**res, "cases": []}, tmp_path / "cycles.png").stat().st_size > 0  # --mix-only --no-mix: cycles alone
