"""The headline figures table: rows from the benchmarks' JSON, committed rows kept where a JSON
is missing, no cell over 300 characters, the README and docs/results/figures.md tables the same."""

from __future__ import annotations

import json
from pathlib import Path

from litevloc.experiments.report import (
    BEGIN,
    END,
    HEADLINES,
    MAX_CELL,
    build_table,
    committed_rows,
    rewrite,
)

ROOT = Path(__file__).resolve().parents[2]


def _write(out: Path, rel: str, data: dict) -> None:
    (out / rel).parent.mkdir(parents=True, exist_ok=True)
    (out / rel).write_text(json.dumps(data))


def test_a_row_comes_from_its_json_and_a_missing_one_keeps_the_committed_row(tmp_path: Path) -> None:
    streams = next(h for h in HEADLINES if h.json == "bench/streams.json")
    _write(tmp_path, streams.json, {"meta": {"time": "2031-02-03T04:05:06+0000", "cpu": "Orin", "cpus": 8,
                                             "load_avg": 0.4}, "replay_fps": 321.0, "replay_vs_folder_ratio": 2.0})
    committed = {"map update, 7-Scenes": ["map update, 7-Scenes", "kept figure", "2030-01-01", "m", "`c`"]}
    log: list[str] = []
    table = build_table(tmp_path, committed, log.append)
    rows = committed_rows(f"{BEGIN}\n{table}\n{END}")
    assert rows["recordings"][1:4] == ["MCAP replay 321 frames/s (decode included), x2.0 the dataset folder",
                                       "2031-02-03", "Orin, 8 CPUs, load 0.4"]
    assert rows["map update, 7-Scenes"][1] == "kept figure"
    assert any("map update" in m and "keeping the committed row" in m for m in log)
    assert set(rows) == {h.what for h in HEADLINES}


def test_a_json_without_the_figure_keeps_the_committed_row(tmp_path: Path) -> None:
    _write(tmp_path, "bench/streams.json", {"meta": {}, "unexpected": 1})
    log: list[str] = []
    committed = {"recordings": ["recordings", "old", "d", "m", "`c`"]}
    rows = committed_rows(f"{BEGIN}\n{build_table(tmp_path, committed, log.append)}\n{END}")
    assert rows["recordings"][1] == "old" and any("has no figure" in m for m in log)


def test_cells_are_cut_at_300_characters(tmp_path: Path) -> None:
    committed = {"recordings": ["recordings", "x" * 1000, "d", "m", "`c`"]}
    table = build_table(tmp_path, committed, lambda _m: None)
    assert max(len(c) for line in table.splitlines() for c in line.split(" | ")) <= MAX_CELL + 2


def test_rewrite_replaces_only_the_table(tmp_path: Path) -> None:
    doc = tmp_path / "d.md"
    doc.write_text(f"intro\n{BEGIN}\nold\n{END}\nrest\n")
    assert rewrite(doc, "| new |") and doc.read_text() == f"intro\n{BEGIN}\n| new |\n{END}\nrest\n"
    assert not rewrite(doc, "| new |")


def test_the_committed_tables_have_every_headline_and_agree() -> None:
    readme = committed_rows((ROOT / "README.md").read_text())
    docs = committed_rows((ROOT / "docs" / "results" / "figures.md").read_text())
    assert set(readme) == {h.what for h in HEADLINES} and readme == docs
    for row in readme.values():
        assert len(row) == 5 and all(len(c) <= MAX_CELL for c in row) and row[2], row


def test_the_splits_row_names_the_splits_under_95_percent_of_covered(tmp_path: Path) -> None:
    def split(name: str, of_covered: float, wrong: int) -> dict:
        return {"split": name, "summary": {"accepted_of_covered_pct": of_covered, "wrong_over_0.5m": wrong,
                                           "accepted_pct": 99.2, "gl_latency_median_ms": 383.4}}

    _write(tmp_path, "bench/splits.json", {"meta": {"time": "2031-02-03T04:05:06"}, "splits": [
        split("B1>B0", 93.79, 0), split("published", 100.0, 1), split("reverse", 97.7, 0)]})
    rows = committed_rows(f"{BEGIN}\n{build_table(tmp_path, {}, lambda _m: None)}\n{END}")
    assert rows["7-Scenes cross-split localization, 8 splits"][1] == (
        "covered frames accepted >= 95 % on 2 of 3 splits (B1>B0 93.8 %), 1 pose > 0.5 m off; "
        "published split 99.2 % accepted, GL median 383 ms")
