"""bench/change.py end to end on two tiny buildings (two 3 x 3 m rooms each, one goal, one case,
one update cycle): the JSON carries the keys issue 78 asks for, and the plot is written; runs
made apart pool into one (`--merge`)."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path
from typing import Any

import pytest

from litevloc.experiments.change import contract
from tests.bench.test_buildings_contract import TINY as BUILDINGS_TINY
from tests.experiments.test_change_pooling import fake_building

TINY = BUILDINGS_TINY.replace("furniture_per_room: [0, 1]", "furniture_per_room: [1, 1]")  # something to move
KEYS = {"gl_accepted_of_covered", "wrong_over_0_5m", "gl_accepted_of_covered_unchanged", "goals_reached",
        "goals_total", "goals_reached_unchanged"}


@pytest.mark.slow
@pytest.mark.skipif(not os.environ.get("LITEVLOC_LONG_TESTS"),
                    reason="~9 min on 2 CPUs, over the suite's budget: set LITEVLOC_LONG_TESTS=1 to run it")
@pytest.mark.timeout(1200)  # three drives, three GL passes and two map updates per building
def test_two_building_run_writes_the_json_contract(tmp_path: Path) -> None:
    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "bench"))
    import change as bench

    world = tmp_path / "tiny.yaml"
    world.write_text(TINY)
    out = tmp_path / "c.json"
    assert bench.main(["--generators", str(world), "--seeds", "1:3", "--levels", "furniture=0.5", "--no-mix",
                       "--cycles", "1", "--max-goals", "1", "--quick", "--out-dir", str(tmp_path / "maps"),
                       "--json", str(out)]) == 0
    res = json.loads(out.read_text())
    assert out.with_suffix(".png").is_file()
    (case,) = res["cases"]
    assert (case["axis"], case["level"]) == ("furniture", 0.5)
    assert set(case) >= KEYS and set(case["after_update"]) >= KEYS
    assert case["goals_total"] == 2 and 0 <= case["goals_reached"] <= 2
    assert 0 <= case["gl_accepted_of_covered"] <= 1 and isinstance(case["wrong_over_0_5m"], int)
    (cycle,) = res["update_cycles"]
    assert set(cycle) == {"cycle", "map_size_ratio", "map_size_ratio_to_first_update",
                          "gl_accepted_of_covered"} and cycle["cycle"] == 1
    assert cycle["map_size_ratio"] > 0 and cycle["map_size_ratio_to_first_update"] == 1.0
    assert [b["building"] for b in res["buildings"]] == ["tiny-1", "tiny-2"]
    for b in res["buildings"]:
        (c,) = b["cases"]
        assert c["truth"]["levels"]["furniture"] == 0.5  # the ground truth of what changed rides along
        assert c["update"]["nodes_after"] >= 1


def test_bad_levels_are_a_usage_error(capsys: pytest.CaptureFixture[str]) -> None:
    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "bench"))
    import change as bench

    with pytest.raises(SystemExit) as exc:
        bench.main(["--levels", "windows=1"])
    assert exc.value.code == 2


def _run(path: Path, names: list[str], scale: int, **settings: Any) -> Path:
    buildings = [{"building": n, **fake_building(scale)} for n in names]
    meta = {"time": f"2026-12-0{scale}T00:00:00+0000", "load_avg": float(scale), "command": f"change.py --run {scale}"}
    path.write_text(json.dumps({"meta": meta, "settings": {"runs": names, "query_every": 30, **settings},
                                "buildings": buildings}))
    return path


def test_merge_pools_runs_made_apart_as_one_run(tmp_path: Path) -> None:
    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "bench"))
    import change as bench

    a, b = _run(tmp_path / "a.json", ["office-1"], 1), _run(tmp_path / "b.json", ["floor-1"], 2)
    out = tmp_path / "m.json"
    assert bench.main(["--merge", str(a), str(b), "--json", str(out)]) == 0
    res = json.loads(out.read_text())
    assert res["cases"] == contract([fake_building(1), fake_building(2)])["cases"]
    assert res["settings"] == {"runs": ["office-1", "floor-1"], "query_every": 30}
    assert (res["meta"]["time"], res["meta"]["load_avg"]) == ("2026-12-02T00:00:00+0000", 2.0)
    assert [m["command"] for m in res["meta"]["merged"]] == ["change.py --run 1", "change.py --run 2"]
    assert out.with_suffix(".png").is_file()


def test_merge_refuses_runs_with_other_settings_or_a_building_twice(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "bench"))
    import change as bench

    a = _run(tmp_path / "a.json", ["office-1"], 1)
    other = _run(tmp_path / "b.json", ["floor-1"], 2, max_goals=3)
    assert bench.main(["--merge", str(a), str(other), "--json", str(tmp_path / "m.json")]) == 2
    assert "other settings" in capsys.readouterr().err and not (tmp_path / "m.json").exists()
    twice = _run(tmp_path / "c.json", ["office-1"], 2)
    assert bench.main(["--merge", str(a), str(twice), "--json", str(tmp_path / "m.json")]) == 2
    assert "a building comes twice" in capsys.readouterr().err
