"""Commands run through the installed `litevloc` console script on small real inputs: the
7-Scenes map of the mapping pass and a second session from the held-out query pass
(`seven_scenes_held_out`, tests/conftest.py). Each command's own logic has unit tests; these
check that the command, as a user types it, does its job end to end.

The maps-that-live commands use the mutual-nearest-neighbour matcher and int8 descriptor codes
(`--set models.matcher=mnn --set mapping.descriptor_bytes=0`): the same code paths at a fraction
of the cost on 2 CPUs (LightGlue per pair; training the product quantiser's codebook was 84 % of a
merge); both are tested on their own elsewhere.
"""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import HeldOut, litevloc_exe

pytestmark = [pytest.mark.shared_data, pytest.mark.slow]
FAST = ["--config", "7scenes", "--set", "models.matcher=mnn", "--set", "mapping.descriptor_bytes=0"]


def litevloc(*args: str | Path, timeout: float = 600) -> subprocess.CompletedProcess[str]:
    r = subprocess.run([litevloc_exe(), *map(str, args)], capture_output=True, text=True, timeout=timeout)
    assert r.returncode == 0, (args, r.stdout[-2000:], r.stderr[-3000:])
    return r


def test_a_second_session_merges_updates_and_diffs(seven_scenes_held_out: HeldOut, tmp_path: Path) -> None:
    """B (6 held-out query frames, mapped as a session of its own) merges into A (the mapping
    pass) with a frame offset near zero, both being in the dataset's frame; A updated from the
    next 12 query frames is a new version with A as its parent; diff compares the two."""
    held = seven_scenes_held_out
    a, b, merged, new = held.map_dir, tmp_path / "b", tmp_path / "merged", tmp_path / "new"
    litevloc("map", "build", held.queries, "--frames", "0:6", "-o", b, *FAST)
    litevloc("map", "merge", a, b, "-o", merged, *FAST, "--json", tmp_path / "merge.json")
    m = json.loads((tmp_path / "merge.json").read_text())
    (s,) = m["sessions"]
    assert s["links_consistent"] >= 3 and s["alignment_translation_m"] < 0.05 and s["alignment_rotation_deg"] < 2
    assert m["nodes"] == s["nodes_a"] + s["nodes_b"] - s["nodes_dropped"]
    litevloc("map", "update", a, held.queries, "--frames", "12:24", "-o", new, *FAST,
             "--set", "mapping.update.align_every=3", "--json", tmp_path / "update.json")
    u = json.loads((tmp_path / "update.json").read_text())
    assert u["posed_session_aligned_by"] >= 3 and u["compared"] >= 4
    assert u["known_place"] + u["new_place"] + u["changed_place"] + u["unreliable"] == u["compared"]
    assert json.loads((new / "manifest.json").read_text())["meta"]["parent_map"] == str(a)
    litevloc("map", "diff", a, new, "--json", tmp_path / "diff.json", "-o", tmp_path / "diff.png")
    d = json.loads((tmp_path / "diff.json").read_text())
    assert d["old_nodes"] == u["nodes_before"] and d["new_nodes"] == u["nodes_after"]
    assert d["retired"] == u["retired"] and d["added"] == u["added"]
    assert (tmp_path / "diff.png").read_bytes()[:4] == b"\x89PNG"


def test_calib_writes_a_preset_block(seven_scenes_dir: Path, tmp_path: Path) -> None:
    """`litevloc calib` on 20 mapping frames: an `rgbd_calibration:` block that loads as a config
    section and a lower reprojection error than the published intrinsics."""
    from litevloc.config import load_config

    out = tmp_path / "calib.yaml"
    r = litevloc("calib", seven_scenes_dir, "--frames", "0:200:10", "-o", out, "--json", tmp_path / "c.json")
    res = json.loads((tmp_path / "c.json").read_text())
    assert res["n_pairs"] >= 3 and res["median_after_px"] < 0.5 * res["median_before_px"], r.stdout
    cal = load_config(out).rgbd_calibration
    assert cal is not None and np.isclose(cal.translation_color_depth[0], -0.025)  # the prior, kept
    assert 450 < cal.color_fx < 600 and 450 < cal.color_fy < 600


def test_info_and_models_list(tmp_path: Path) -> None:
    litevloc("info", "--json", tmp_path / "info.json")
    info = json.loads((tmp_path / "info.json").read_text())
    assert "CPUExecutionProvider" in info["onnxruntime_providers"] and "7scenes" in info["presets"]
    r = litevloc("models", "list", "--json", tmp_path / "models.json")
    ids = {m["id"] for m in json.loads((tmp_path / "models.json").read_text())["models"]}
    assert "aliked-n16-240x320-k512" in ids and "aliked-n16-240x320-k512" in r.stdout
