"""`litevloc bench fusion` end to end on a short 7-Scenes slice."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from litevloc.pipelines.evaluation.trajectory import read_tum
from litevloc.runtime.cli.main import main


@pytest.mark.shared_data
def test_bench_fusion_writes_the_table_json(
    seven_scenes_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "fusion.json"
    rc = main(
        [
            "bench",
            "fusion",
            str(seven_scenes_dir),
            "--frames",
            "500:800",
            "--seeds",
            "1",
            "--json",
            str(out),
            "--tum-dir",
            str(tmp_path / "tum"),
        ]
    )
    assert rc == 0
    d = json.loads(out.read_text())
    for k in ("odometry", "vloc", "fused", "batch"):
        assert d["ate_m"][k] >= 0
        assert d["rate_hz"][k] > 0
    assert d["rate_hz"]["odometry"] == pytest.approx(100.0, rel=0.01)
    assert d["rate_hz"]["fused"] == pytest.approx(100.0, rel=0.01)
    assert "fused kernel+gate" in capsys.readouterr().out
    t, P = read_tum(tmp_path / "tum" / "fused_robust.txt")
    assert P.shape == (len(t), 4, 4)
    assert len(t) > 0.7 * 100 * d["duration_s"]  # 100 Hz output from initialisation (~2 s) on
    for name in ("ground_truth", "odometry", "vloc", "batch_no_robust"):
        assert (tmp_path / "tum" / f"{name}.txt").is_file()


def test_bench_fusion_bad_source_is_a_user_error(tmp_path: Path) -> None:
    assert main(["bench", "fusion", str(tmp_path / "nope")]) == 2
