"""The map-free layout written, read back and scored; malformed submissions are named errors."""

from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np
import pytest

from litevloc.base.geometry import invert, make_T, so3_exp
from litevloc.experiments.mapfree_submission import (
    MapFreeQuery,
    SubmissionError,
    score_submission,
    write_dataset,
    write_submission,
)
from litevloc.pipelines.evaluation.mapfree import mapfree_metrics, score_query

K = np.array([[520.0, 0, 320], [0, 520.0, 240], [0, 0, 1]])


def _queries(n: int = 12) -> list[MapFreeQuery]:
    rng = np.random.default_rng(0)
    return [MapFreeQuery(500 + 5 * i, 3 if i < 7 else 11, K, (640, 480),
                         make_T(so3_exp(rng.normal(0, 0.2, 3)), rng.normal(0, 0.5, 3))) for i in range(n)]


def test_written_layout_scores_like_the_direct_computation(tmp_path: Path) -> None:
    qs = _queries()
    write_dataset(tmp_path, qs)
    rng = np.random.default_rng(1)
    est: dict[int, tuple[int, np.ndarray, float]] = {}
    direct: dict[str, list] = {"kf0003": [], "kf0011": []}
    for q in qs[:-2]:  # the last two queries have no estimate
        T = q.T_ref_query_gt @ make_T(so3_exp(rng.normal(0, 0.02, 3)), rng.normal(0, 0.05, 3))
        conf = float(rng.integers(20, 300))
        est[q.source_index] = (q.reference, T, conf)
        direct[f"kf{q.reference:04d}"].append(score_query(invert(T), invert(q.T_ref_query_gt), K, 640, 480, conf))
    z = write_submission(tmp_path / "submission_x.zip", est)
    with zipfile.ZipFile(z) as f:
        assert sorted(f.namelist()) == ["pose_kf0003.txt", "pose_kf0011.txt"]
        first = f.read("pose_kf0003.txt").decode().splitlines()[0].split()
    assert first[0] == "seq1/frame_00500.jpg" and len(first) == 9
    assert sorted(p.name for p in (tmp_path / "dataset" / "val").iterdir()) == ["kf0003", "kf0011"]
    got = score_submission(z, tmp_path / "dataset" / "val")
    want = mapfree_metrics(direct, failures=2)
    assert got.keys() == want.keys()
    for k in want:
        assert got[k] == pytest.approx(want[k], rel=1e-6, abs=1e-9), k
    assert got["Estimates for % of frames"] == pytest.approx(10 / 12)
    # the official split keeps every 5th ground-truth frame of each scene
    sub = score_submission(z, tmp_path / "dataset" / "val", subsample=5)
    assert sub["Estimates for % of frames"] == pytest.approx(3 / 3)  # frames 0, 5 of kf0003 and 0 of kf0011


def test_malformed_submissions_are_named_errors(tmp_path: Path) -> None:
    qs = _queries(3)
    write_dataset(tmp_path, qs)
    bad = tmp_path / "bad.zip"
    with zipfile.ZipFile(bad, "w") as f:
        f.writestr("pose_kf0003.txt", "seq1/frame_00500.jpg 1 0 0 0 0 0 0\n")  # no confidence
    with pytest.raises(SubmissionError, match="line 1: 8 fields"):
        score_submission(bad, tmp_path / "dataset" / "val")
    with zipfile.ZipFile(bad, "w") as f:
        f.writestr("pose_kf0003.txt", "seq1/frame_00500.jpg nan 0 0 0 0 0 0 5\n")
    with pytest.raises(SubmissionError, match="non-finite"):
        score_submission(bad, tmp_path / "dataset" / "val")
    with pytest.raises(SubmissionError, match="no submission zip"):
        score_submission(tmp_path / "missing.zip", tmp_path / "dataset" / "val")
    with pytest.raises(SubmissionError, match="does not fit"):
        write_submission(tmp_path / "x.zip", {123456: (3, np.eye(4), 1.0)})


def test_a_scene_without_a_pose_file_fails_with_all_its_frames(tmp_path: Path) -> None:
    """The official scorer's rule: a scene with no pose file counts every ground-truth frame as
    a failure (its every-5th subsampling applies only to scenes that have a file)."""
    qs = _queries(12)  # kf0003: 7 queries, kf0011: 5 queries
    write_dataset(tmp_path, qs)
    est = {q.source_index: (q.reference, q.T_ref_query_gt, 100.0) for q in qs if q.reference == 3}
    z = write_submission(tmp_path / "s.zip", est)
    split = tmp_path / "dataset" / "val"
    assert score_submission(z, split)["Estimates for % of frames"] == pytest.approx(7 / 12)
    # every 5th of kf0003 (frames 0 and 5: 2 estimated) + all 5 frames of kf0011 as failures
    assert score_submission(z, split, subsample=5)["Estimates for % of frames"] == pytest.approx(2 / 7)
