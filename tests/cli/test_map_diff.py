"""`litevloc map diff OLD NEW` end to end on saved maps (table, JSON, PNG, errors)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from litevloc.cli.main import main
from litevloc.pipelines.topomap.map_save import save_map
from tests.pipelines.topomap.test_diff import camera, grid, make_map


def _jpeg(level: int) -> bytes:
    return cv2.imencode(".jpg", np.full((48, 64, 3), level, np.uint8))[1].tobytes()


@pytest.fixture()
def two_maps(tmp_path: Path) -> tuple[Path, Path]:
    a, b, c, d = (_jpeg(v) for v in (10, 80, 150, 220))
    old = make_map([camera(0, 0), camera(2, 0), camera(4, 0)], [a, b, c], grid(slice(0, 10), slice(0, 4)))
    new = make_map([camera(0, 0), camera(2.2, 0), camera(8, 0)], [a, b, d], grid(slice(0, 18), slice(0, 4)))
    return save_map(old, tmp_path / "old"), save_map(new, tmp_path / "new")


def test_map_diff_cli(two_maps: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    old, new = two_maps
    png, js = tmp_path / "diff.png", tmp_path / "diff.json"
    assert main(["map", "diff", str(old), str(new), "-o", str(png), "--json", str(js)]) == 0
    out = capsys.readouterr().out
    assert "retired" in out and "added" in out and "moved" in out
    s = json.loads(js.read_text())
    assert (s["kept"], s["moved"], s["retired"], s["added"]) == (2, 1, 1, 1)
    assert s["retired_ids"] == [2] and s["added_ids"] == [2] and s["moved_ids"] == [[1, 1]]
    assert s["moved_max_m"] == pytest.approx(0.2)
    assert png.stat().st_size > 10_000


def test_map_diff_refuses_other_ground_plane(two_maps: tuple[Path, Path], tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    old, _ = two_maps
    tilted = make_map([camera(0, 0)], [_jpeg(10)], dataclasses.replace(grid(slice(0, 2), slice(0, 2)),
                                                                      up=np.array([0.0, 1.0, 0.0])))
    other = save_map(tilted, tmp_path / "tilted")
    assert main(["map", "diff", str(old), str(other)]) == 2
    assert "ground planes" in capsys.readouterr().err


def test_map_diff_missing_map(tmp_path: Path, two_maps: tuple[Path, Path]) -> None:
    assert main(["map", "diff", str(two_maps[0]), str(tmp_path / "nope")]) == 2


def test_map_merge_cli_refusals(two_maps: tuple[Path, Path], tmp_path: Path,
                                capsys: pytest.CaptureFixture[str]) -> None:
    old, new = two_maps
    assert main(["map", "merge", str(old), "-o", str(tmp_path / "m")]) == 2
    assert "at least two maps" in capsys.readouterr().err
    assert main(["map", "merge", str(old), str(new), "-o", str(old), "--force"]) == 2
    assert "must not be one of the inputs" in capsys.readouterr().err
    assert main(["map", "merge", str(old), str(new), "-o", str(new)]) == 2  # exists, no --force
