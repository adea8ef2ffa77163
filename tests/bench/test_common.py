"""bench/_common.py: where a benchmark's JSON goes."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tests.bench import load_bench


def test_write_json_takes_a_name_under_out_bench_or_a_path(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    common = load_bench("_common")
    monkeypatch.setattr(common, "OUT", tmp_path / "out")
    by_name = common.write_json("slam", {"x": 1})
    assert by_name == tmp_path / "out" / "slam.json"
    target = tmp_path / "elsewhere" / "run.json"
    by_path = common.write_json(str(target), {"x": 2})
    assert by_path == target and json.loads(target.read_text())["x"] == 2
    assert not Path(f"{target}.json").exists()  # what a path given as a name used to become


def test_a_table_without_rows_prints_its_header(capsys: pytest.CaptureFixture[str]) -> None:
    load_bench("_common").print_table("nothing measured", ["case", "ATE m"], [])
    out = capsys.readouterr().out
    assert "nothing measured" in out and "case  ATE m" in out
