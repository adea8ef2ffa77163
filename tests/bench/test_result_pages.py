"""The per-benchmark result pages: a page's table comes from its JSON, a page whose JSON is missing
keeps its committed table, and every page is committed, generated and dated."""

from __future__ import annotations

import json
import re
from pathlib import Path

from litevloc.experiments.report import BEGIN, END
from litevloc.experiments.result_pages import PAGES, committed_block, page_text, update_pages

ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "docs" / "results"


def _split(name: str, role: str, covered: float) -> dict:
    return {"split": name, "role": role, "summary": {
        "covered_pct": covered, "accepted_pct": 80.0, "accepted_of_covered_pct": 99.5, "within_5cm_5deg_pct": 70.25,
        "median_cm": 2.5, "max_cm": 12.34, "wrong_over_0.5m": 0, "vpr_recall@10_covered_pct": 96.0,
        "gl_latency_median_ms": 512.4}}


def test_a_page_comes_from_its_json_and_a_missing_one_keeps_its_committed_table(tmp_path: Path) -> None:
    out, results = tmp_path / "out", tmp_path / "results"
    (out / "bench").mkdir(parents=True)
    results.mkdir()
    (out / "bench" / "splits.json").write_text(json.dumps({
        "meta": {"time": "2031-02-03T04:05:06+0000", "cpu": "Orin", "cpus": 8, "load_avg": 0.4},
        "splits": [_split("B0>B1", "choose", 24.4), _split("published", "report", 64.0)]}))
    gate = next(p for p in PAGES if p.name == "prior_gate")
    (results / "prior_gate.md").write_text(page_text(gate, "Measured 2030-01-01 ...\n\n| kept |"))
    log: list[str] = []
    update_pages(out, results, log.append)
    splits = (results / "splits.md").read_text()
    assert "Measured 2031-02-03 on Orin, 8 CPUs, load 0.4 with `python bench/splits.py`." in splits
    assert "| B0>B1* | 24.4 | 80.0 | 99.5 | 70.2 | 2.50 / 12.3 | 0 | 96 | 512 |" in splits
    assert "| published | 64.0 |" in splits
    assert committed_block((results / "prior_gate.md").read_text()) == "Measured 2030-01-01 ...\n\n| kept |"
    assert any("prior_gate" in m and "keeping the committed table" in m for m in log)


def test_a_json_without_the_figure_keeps_the_committed_table(tmp_path: Path) -> None:
    out, results = tmp_path / "out", tmp_path / "results"
    (out / "bench").mkdir(parents=True)
    results.mkdir()
    (out / "bench" / "splits.json").write_text(json.dumps({"meta": {}, "unexpected": 1}))
    page = next(p for p in PAGES if p.name == "splits")
    (results / "splits.md").write_text(page_text(page, "old table"))
    log: list[str] = []
    update_pages(out, results, log.append)
    assert committed_block((results / "splits.md").read_text()) == "old table"
    assert any("has no figure" in m for m in log)


def test_every_page_is_committed_as_generated_and_dated() -> None:
    for page in PAGES:
        text = (RESULTS / f"{page.name}.md").read_text()
        block = committed_block(text)
        assert block is not None and text == page_text(page, block), page.name
        assert re.match(r"Measured \d{4}-\d{2}-\d{2} on ", block), block[:80]
        assert BEGIN in text and END in text


def test_a_slam_case_without_ground_truth_shows_a_dash_and_non_cases_are_skipped(tmp_path: Path) -> None:
    out, results = tmp_path / "out", tmp_path / "results"
    (out / "bench").mkdir(parents=True)
    results.mkdir()
    case = {"keyframe_ate_m": 0.0058, "odometry_ate_m": 2.23, "no_loop_ate_m": None, "loops_kept": 181,
            "wrong_loops_kept": 0, "s_per_keyframe": 0.94, "cpu_s_per_keyframe": 1.4, "map_keyframes": 158,
            "slam_keyframes": 1164}
    robot = {**case, "keyframe_ate_m": None, "odometry_ate_m": None, "wrong_loops_kept": None}
    (out / "bench" / "slam.json").write_text(json.dumps({"meta": {"time": "2031-02-03"}, "office": case,
                                                         "robot": robot, "notes": "not a case"}))
    update_pages(out, results, lambda _m: None)
    rows = [line for line in (results / "slam.md").read_text().splitlines() if line.startswith("| ")][1:]
    assert rows == ["| office | 0.6 | 223 | - | 181 | 0 | 0.94 (1.4) | 158 / 1164 |",
                    "| robot | - | - | - | 181 | - | 0.94 (1.4) | 158 / 1164 |"]


def test_a_page_of_pooled_runs_names_each_run_s_command(tmp_path: Path) -> None:
    out, results = tmp_path / "out", tmp_path / "results"
    (out / "bench").mkdir(parents=True)
    results.mkdir()
    (out / "bench" / "splits.json").write_text(json.dumps({
        "meta": {"time": "2031-02-03T04:05:06+0000", "cpu": "Orin", "cpus": 8, "load_avg": 2.0,
                 "command": "splits.py --merge a.json b.json",
                 "merged": [{"command": "splits.py --splits B0>B1"}, {"command": "splits.py --splits published"}]},
        "splits": [_split("B0>B1", "choose", 24.4), _split("published", "report", 64.0)]}))
    update_pages(out, results, lambda _: None)
    assert ("with `python bench/splits.py --merge a.json b.json`, pooling `python bench/splits.py --splits B0>B1` "
            "and `python bench/splits.py --splits published`.") in (results / "splits.md").read_text()
