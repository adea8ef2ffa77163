"""The cross-split benchmark's rule, failure analysis, summary and model replay (no models, no data)."""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from litevloc.experiments.model_replay import ReplayedModels
from litevloc.experiments.split_report import failure_of, reason_key, summarize
from litevloc.experiments.splits import SPLITS, splits_named
from litevloc.pipelines.localization.results import CandidateAttempt, LocalizationResult


def test_split_rule_is_the_stated_one() -> None:
    names = [s.name for s in SPLITS]
    assert names == ["B0>B1", "B1>B0", "B1>B2", "B2>B1", "B2>B3", "B3>B2", "published", "reverse"]
    assert [s.name for s in SPLITS if s.role == "choose"] == ["B0>B1", "B1>B0"]
    for s in SPLITS:
        m, q = range(*s.map_frames), range(*s.query_frames)
        assert not set(m) & set(q), s.name  # queries are never mapped
        assert len(q) in (250, 500) and max(q) < 1000
    pub = splits_named(["published"])[0]
    assert (pub.map_frames, pub.query_frames, pub.role) == ((0, 500), (500, 1000), "report")
    with pytest.raises(ValueError, match="unknown split"):
        splits_named(["B0>B3"])


def _gl(attempts: list[tuple[int, int, str]], reason: str = "not localized: no VPR candidate verified",
        mode: str = "global") -> LocalizationResult:
    return LocalizationResult(0, mode, False, reason,
                              attempts=tuple(CandidateAttempt(n, 0.5, 100, i, r) for n, i, r in attempts))


def test_failure_of_names_the_stage_that_lost_the_covered_frame() -> None:
    top = [4, 5, 6]
    assert failure_of(_gl([(4, 10, "x")]), {9}, top) == "retrieval: no covering keyframe in the shortlist"
    reranked = replace(_gl([(4, 10, "x")]), candidates=(4, 5))
    assert failure_of(reranked, {6}, top) == "re-ranking: no covering keyframe among the verified"
    assert failure_of(_gl([(4, 10, "x")]), {6}, top) == "stopped before a covering candidate"
    res = _gl([(4, 80, "joint refinement rejected: only 1 keyframe(s) consistent with the joint pose (< 2)"),
               (6, 30, "too few inliers (30 < 40)"), (5, 12, "too few inliers (12 < 40)")])
    assert failure_of(res, {5, 6}, top) == "covering candidate: too few inliers"  # the best covering one
    ll = _gl([], "not localized: no candidate verified", mode="local")
    assert failure_of(ll, {5}, top) == "LL: not localized: no candidate verified"
    assert reason_key("pose 6.1 m from its reference node (> 5.0)") == "pose N m from its reference node"


def _rec(frame: int, accepted: bool, covered: bool, err: tuple[float, float] = (0.0, 0.0), rank: int = 1,
         failure: str = "", mode: str = "global") -> dict[str, Any]:
    r: dict[str, Any] = {"frame": frame, "mode": mode, "accepted": accepted, "covered": covered, "near": covered,
                         "first_covering_rank": rank if covered else -1, "latency_ms": 100.0 + frame}
    if accepted:
        r["error_m"], r["error_deg"] = err
    elif covered:
        r["failure"] = failure
    return r


def test_summary_counts_what_the_table_reports() -> None:
    recs = [_rec(0, True, True, (0.02, 1.0)), _rec(1, True, True, (0.08, 1.0), rank=7),
            _rec(2, False, True, rank=12, failure="retrieval: no covering keyframe in the shortlist"),
            _rec(3, True, False, (0.6, 3.0)), _rec(4, False, False)]
    s = summarize(recs)
    assert (s["queries"], s["accepted"], s["covered"]) == (5, 3, 3)
    assert s["accepted_of_covered_pct"] == pytest.approx(200 / 3)
    assert s["within_5cm_5deg_pct"] == pytest.approx(20.0)
    assert s["wrong_over_0.5m"] == 1 and s["accepted_uncovered"] == 1
    assert s["median_cm"] == pytest.approx(8.0) and s["max_cm"] == pytest.approx(60.0)
    assert [s[f"vpr_recall@{k}_covered_pct"] for k in (1, 5, 10)] == pytest.approx([100 / 3, 100 / 3, 200 / 3])
    assert s["covered_refused_by_reason"] == {"retrieval: no covering keyframe in the shortlist": 1}
    assert s["gl_latency_median_ms"] == pytest.approx(102.0)


class _Bundle:
    """Model stand-ins that count their calls and take a known time."""

    def __init__(self) -> None:
        self.extractor = SimpleNamespace(name="ex")
        self.vpr = SimpleNamespace(name="vpr")
        self.matcher = SimpleNamespace(name="lg")
        self.max_keypoints = 0
        self.calls = 0

    def extract(self, img: np.ndarray) -> Any:
        self.calls += 1
        return SimpleNamespace(keypoints=np.full((3, 2), img[0, 0, 0], np.float32),
                               descriptors=np.eye(3, dtype=np.float32), scores=np.ones(3, np.float32),
                               image_size=(4, 4))

    def describe(self, img: np.ndarray) -> np.ndarray:
        self.calls += 1
        return np.array([1.0, 0.0], np.float32)

    def match(self, live: Any, ref: Any) -> tuple[np.ndarray, np.ndarray]:
        self.calls += 1
        time.sleep(0.02)
        return np.array([0, 1]), np.array([int(ref.keypoints[0, 0]) % 3, 2])


def test_replayed_models_return_the_recorded_calls_and_count_their_time(tmp_path: Path) -> None:
    (tmp_path / "map").mkdir()
    (tmp_path / "map" / "manifest.json").write_text("{}")
    kf = [SimpleNamespace(keypoints=np.full((2, 2), float(i), np.float32)) for i in range(3)]
    topomap: Any = SimpleNamespace(features=kf, n_nodes=3)
    img = np.full((4, 4, 3), 7, np.uint8)
    outputs = []
    for run in range(2):
        bundle = _Bundle()
        rm = ReplayedModels(tmp_path / "cache", bundle, topomap, tmp_path / "map")  # type: ignore[arg-type]
        rm.start(11)
        t0 = rm.clock()
        f = rm.extract(img)
        outputs.append((f.keypoints.copy(), rm.describe(img), rm.match(f, kf[1]), rm.match(f, kf[2])))
        elapsed = rm.clock() - t0
        rm.flush()
        assert bundle.calls == (4 if run == 0 else 0)
        assert elapsed >= 0.04  # replayed matches still take their recorded time on the clock
    for a, b in zip(outputs[0], outputs[1], strict=True):
        np.testing.assert_array_equal(np.asarray(a, dtype=object).tolist(), np.asarray(b, dtype=object).tolist())
    assert outputs[1][2][1].tolist() == [1, 2] and outputs[1][3][1].tolist() == [2, 2]
