"""`litevloc bench fusion` end to end on a short 7-Scenes slice."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from litevloc.cli.main import main
from litevloc.pipelines.evaluation.trajectory import read_tum


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
    ate = d["ate_m"]
    for k in ("odometry", "vloc", "fused", "batch"):
        assert d["rate_hz"][k] > 0
    # Seeded inputs (d["inputs"]): 10 s of 100 Hz drift odometry, 1 Hz VLoc with 5 cm / 2 deg noise and
    # 10 % outliers. Measured on frames 500:800: odometry 0.001, VLoc 0.087, fused 0.011, batch 0.002 m.
    assert 0 < ate["odometry"] < 0.05  # aligned drift over 10 s; 0 would mean GT compared with itself
    assert 0.03 < ate["vloc"] < 0.3  # the simulated VLoc noise (~sqrt(3) x 5 cm) shows through
    assert 0 < ate["fused"] < 0.5 * ate["vloc"] and 0 < ate["batch"] < 0.5 * ate["vloc"]  # fusion beats VLoc
    assert d["ate_m_all"]["fused_robust"] <= d["ate_m_all"]["fused_no_robust"]  # kernel+gate vs outliers
    assert d["ate_m_all"]["batch_robust"] <= d["ate_m_all"]["batch_no_robust"]
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
