"""End-to-end CLI on real data: map info/plot, bench reloc (held-out 7-Scenes frames in the map of
the mapping pass; `litevloc localize` on them: tests/test_readme.py)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from litevloc.cli.main import main
from tests.conftest import HeldOut


@pytest.fixture(scope="module")
def small_map(seven_scenes_held_out: HeldOut) -> Path:
    """The map of the mapping pass (frames 0:500:5), built through the console script."""
    return seven_scenes_held_out.map_dir


def test_map_build_info_plot(small_map: Path, tmp_path: Path) -> None:
    manifest = json.loads((small_map / "manifest.json").read_text())
    assert 2 <= manifest["nodes"] <= 40 and float(manifest["meta"]["keyframe_coverage"]) > 0.5
    assert main(["map", "info", str(small_map), "--json", str(tmp_path / "i.json")]) == 0
    info = json.loads((tmp_path / "i.json").read_text())
    for key in ("nodes", "covisibility_edges", "connectivity_edges", "graph_bytes", "descriptor_bytes",
                "feature_bytes", "image_bytes"):
        assert key in info
    assert info["nodes"] == manifest["nodes"] and info["extractor"] == "aliked-n16"
    assert main(["map", "plot", str(small_map), "-o", str(tmp_path / "m.png")]) == 0
    assert (tmp_path / "m.png").read_bytes()[:4] == b"\x89PNG"
    assert main(["map", "build", "/nonexistent", "-o", str(tmp_path / "x")]) == 2


def test_bench_reloc_classical(small_map: Path, seven_scenes_dir: Path, tmp_path: Path) -> None:
    assert main(["bench", "reloc", str(small_map), str(seven_scenes_dir), "--frames", "530:590:20", "--config",
                 "7scenes", "--methods", "orb+nn-ratio@240x320", "sift+nn-ratio@240x320",
                 "--poses-dir", str(tmp_path), "--json", str(tmp_path / "r.json")]) == 0
    res = json.loads((tmp_path / "r.json").read_text())
    assert set(res["methods"]) == {"orb+nn-ratio@240x320", "sift+nn-ratio@240x320"}
    assert res["methods"]["sift+nn-ratio@240x320"]["queries"] == 3
    # the map-free layout: scored from the files, consistent with our own errors
    sift = res["methods"]["sift+nn-ratio@240x320"]
    mf = sift["mapfree"]["all_queries"]
    assert Path(sift["mapfree"]["submission"]).is_file() and (tmp_path / "references.csv").is_file()
    refs = (tmp_path / "references.csv").read_text().splitlines()
    assert refs[0] == "scene,frame,source_index,reference_keyframe" and len(refs) == 4
    assert refs[1].split(",")[1] == "seq1/frame_00530.jpg"
    assert abs(mf["Estimates for % of frames"] - sift["pct_estimated"] / 100) < 1e-9
    if sift["estimated"] == 3:  # one scene or several: with every query estimated the medians agree
        assert mf["Average Median Translation Error"] > 0
    assert main(["bench", "reloc", str(small_map), str(seven_scenes_dir), "--methods", "bad"]) == 2
