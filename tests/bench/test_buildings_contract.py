"""bench/buildings.py end to end on two tiny buildings (two 3 x 3 m rooms each, one goal): the
JSON carries the keys issue 42 asks for, per building and in total, and the plot is written."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

TINY = """name: tiny
layout: grid
rows: 1
cols: 2
room_size: [3.2, 3.0]
room_size_jitter: 0.0
furniture_per_room: [0, 1]
clutter_per_room: [0, 1]
posters_per_room: [2, 3]
texture_poor_fraction: 0.0
repetitive_fraction: 0.0
"""


@pytest.mark.slow
def test_two_building_run_writes_the_json_contract(tmp_path: Path) -> None:
    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "bench"))
    import buildings as bench

    world = tmp_path / "tiny.yaml"
    world.write_text(TINY)
    out = tmp_path / "b.json"
    assert bench.main(["--generators", str(world), "--seeds", "1:3", "--workers", "1", "--render-frames", "0",
                       "--goal-timeout", "40", "--out-dir", str(tmp_path / "maps"), "--json", str(out)]) == 0
    res = json.loads(out.read_text())
    assert out.with_suffix(".png").is_file()
    assert [b["building"] for b in res["buildings"]] == ["tiny-1", "tiny-2"]
    partial = [json.loads(line) for line in out.with_suffix(".partial.jsonl").read_text().splitlines()]
    assert sorted(b["building"] for b in partial) == ["tiny-1", "tiny-2"]  # kept as each finished
    assert all("litevloc" in b and "ground-truth" in b for b in partial)
    for b in res["buildings"]:
        assert "error" not in b, b.get("error")
        assert {"keyframes", "free_space_coverage", "rooms_entered", "unmapped_openings", "openings",
                "build_wall_s"} <= set(b["map"])
        assert b["map"]["rooms_entered"] == 2
        assert {"wall_s", "cpu_s", "litevloc", "ground-truth", "other_set", "figures", "start"} <= set(b)
        f = b["figures"]
        for mode in ("litevloc", "ground-truth"):
            assert {"reached", "goals", "refused", "wrong_placements", "failures", "collisions", "first_fix_s",
                    "lost_max_s", "time_s", "path_m", "wall_s"} <= set(f[mode])
            assert f[mode]["goals"] == 1
            (g,) = b[mode]["goals"]
            assert {"name", "camera", "outcome", "reason", "placed_node", "placement_error_m", "time_s",
                    "path_length_m"} <= set(g)
        assert {"path_ratio", "time_ratio", "by_camera"} <= set(f)
        assert len(b["other_set"]) == 1 and b["other_set"][0]["camera"] != b["litevloc"]["goals"][0]["camera"]
    t = res["totals"]
    assert t["buildings"] == 2 and t["errors"] == 0
    assert {"reached", "goals", "refused", "wrong_placements", "collisions", "buildings_without_collision",
            "failures", "lost_max_s", "never_fixed"} <= set(t["litevloc"])
    assert t["litevloc"]["goals"] == 2
    assert {"path_ratio", "time_ratio", "by_camera", "map", "wall_s", "cpu_s", "run_wall_s", "acceptance"} <= set(t)
    assert set(t["by_camera"]) == {"robot", "hand"}
    assert set(t["acceptance"]) == {"reached_share", "reached_vs_ground_truth", "wrong_placements",
                                    "buildings_without_collision", "lost_max_s"}
    # the same buildings reported again from the partial record: the same totals; named twice: an error
    again = tmp_path / "again.json"
    assert bench.main(["--combine", str(out.with_suffix(".partial.jsonl")), "--json", str(again)]) == 0
    c = json.loads(again.read_text())
    assert c["totals"]["litevloc"] == t["litevloc"] and c["totals"]["acceptance"] == t["acceptance"]
    with pytest.raises(SystemExit, match="named twice"):
        bench.main(["--combine", str(out), str(again), "--json", str(tmp_path / "twice.json")])
