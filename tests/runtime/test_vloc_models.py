from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from litevloc.base.params.localization import LocalizationParams, SecondLookParams
from litevloc.base.params.models import ModelsConfig
from litevloc.models.registry import ModelError
from litevloc.models.types import Features, Matches
from litevloc.runtime.vloc_models import ExtractOnFirstCall, ModelBundle, second_look_for


class EchoMatcher:
    """Matches keypoint i of f0 with keypoint i of f1 (both already truncated)."""

    name = "echo"

    def match(self, f0: Features, f1: Features) -> Matches:
        n = min(len(f0.keypoints), len(f1.keypoints))
        idx = np.arange(n, dtype=np.int64)
        return Matches(idx, idx, np.ones(n, np.float32))


def feats(scores: list[float]) -> Features:
    n = len(scores)
    kp = np.stack([np.arange(n), np.arange(n)], 1).astype(np.float32)
    return Features(kp, np.eye(n, 8, dtype=np.float32), np.array(scores, np.float32), (64, 48))


def test_top_n_matching_returns_indices_into_the_full_sets() -> None:
    b = ModelBundle(extractor=None, matcher=EchoMatcher(), vpr=None, max_keypoints=2)  # type: ignore[arg-type]
    i0, i1 = b.match(feats([0.1, 0.9, 0.5, 0.8]), feats([0.7, 0.2, 0.95]))
    assert i0.tolist() == [1, 3] and i1.tolist() == [0, 2]  # the two best of each, original order
    b.max_keypoints = 0
    i0, _ = b.match(feats([0.1, 0.9, 0.5]), feats([0.7, 0.2, 0.95]))
    assert i0.tolist() == [0, 1, 2]


def test_the_second_look_is_built_only_when_on_and_a_missing_model_names_its_export(tmp_path: Path) -> None:
    from litevloc.models.registry import configured_ids

    models = ModelsConfig(cache_dir=str(tmp_path))  # an empty model cache
    topomap = None  # never read when the second look is off, nor before its model is found
    off = LocalizationParams(second_look=SecondLookParams(candidates=0))
    assert second_look_for(topomap, models, off, None) is None  # type: ignore[arg-type]
    on = LocalizationParams(second_look=SecondLookParams(candidates=2))
    with pytest.raises(ModelError, match=r"aliked-n16-480x640-k2048.*litevloc models export|litevloc models export.*"
                                         r"aliked-n16-480x640-k2048"):
        second_look_for(topomap, models, on, ModelBundle(EchoExtractor(), EchoMatcher(), None))  # type: ignore[arg-type]
    assert "aliked-n16-480x640-k2048" in configured_ids(models)  # `litevloc models export` builds it


class EchoExtractor:
    name = "aliked-n16"

    def extract(self, image_rgb: np.ndarray) -> Features:
        return feats([float(image_rgb.mean())])


def test_the_second_look_s_extractor_is_loaded_on_its_first_call_only() -> None:
    loads: list[int] = []

    def load() -> EchoExtractor:
        loads.append(1)
        return EchoExtractor()

    extract = ExtractOnFirstCall(load)  # type: ignore[arg-type]
    assert loads == []
    image = np.zeros((4, 4, 3), np.uint8)
    extract(image)
    extract(image)
    assert loads == [1]


def test_the_second_look_matches_only_its_strongest_keypoints_where_configured(monkeypatch: pytest.MonkeyPatch) -> None:
    from litevloc.runtime import vloc_models
    from tests.pipelines.localization.test_vloc import make_map

    monkeypatch.setattr(vloc_models, "check_extractor", lambda name, cfg: None)  # no model cache needed
    on = LocalizationParams(second_look=SecondLookParams(candidates=2))
    bundle = ModelBundle(EchoExtractor(), EchoMatcher(), None, max_keypoints=1)  # type: ignore[arg-type]
    a, b = feats([0.1, 0.9, 0.5, 0.8]), feats([0.7, 0.2, 0.95])
    for n, want in ((2, [1, 3]), (0, [0, 1, 2])):  # 0: every keypoint, not the first look's strongest 1
        look = second_look_for(make_map([0.0, 1.0]), ModelsConfig(second_look_match_keypoints=n), on, bundle)
        assert look is not None
        assert look.local.verifier.match(a, b)[0].tolist() == want
