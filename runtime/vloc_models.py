"""Glue: the model layer's objects as the callables the pure pipelines take.

`pipelines` never imports onnxruntime; this module builds extractor, matcher and place
recognizer from the `models` config and exposes `extract`, `match` (index arrays) and
`describe` with the signatures `pipelines.topomap` and `pipelines.localization` expect.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from litevloc.base.params.localization import LocalizationParams
from litevloc.base.params.models import ModelsConfig
from litevloc.models.registry import (
    ModelError,
    check_extractor,
    load_extractor,
    load_matcher,
    load_place_recognizer,
)
from litevloc.models.types import FeatureExtractor, Features, Matcher, PlaceRecognizer
from litevloc.pipelines.localization.query import Clock
from litevloc.pipelines.localization.second_look import SecondLook
from litevloc.pipelines.topomap.types import FeatureSet, FeatureStore, TopoMap


def as_features(f: FeatureSet, image_size: tuple[int, int] | None = None) -> Features:
    """Any FeatureSet (e.g. the map's cached NodeFeatures) as the model layer's Features."""
    if isinstance(f, Features):
        return f
    size = image_size if image_size is not None else getattr(f, "image_size", None)
    if size is None:
        raise ValueError("features need an image size for the matcher")
    return Features(np.asarray(f.keypoints, np.float32), np.asarray(f.descriptors), np.asarray(f.scores, np.float32),
                    (int(size[0]), int(size[1])))


@dataclass
class ModelBundle:
    """Extractor + matcher + place recognizer, with pipeline-shaped call signatures."""

    extractor: FeatureExtractor
    matcher: Matcher
    vpr: PlaceRecognizer
    max_keypoints: int = 0  # match only the N highest-scoring keypoints of each side; 0 = all

    def extract(self, image_rgb: NDArray[np.uint8]) -> Features:
        return self.extractor.extract(image_rgb)

    def _top(self, f: FeatureSet) -> tuple[Features, NDArray[np.int64] | None]:
        ff = as_features(f)
        n = self.max_keypoints
        if n <= 0 or len(ff.keypoints) <= n:
            return ff, None
        keep = np.sort(np.argsort(-ff.scores, kind="stable")[:n])
        return Features(ff.keypoints[keep], ff.descriptors[keep], ff.scores[keep], ff.image_size), keep

    def match(self, f0: FeatureSet, f1: FeatureSet) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        """Match; indices refer to the full keypoint arrays even when only the top-N were matched."""
        a, ka = self._top(f0)
        b, kb = self._top(f1)
        m = self.matcher.match(a, b)
        i0 = m.idx0 if ka is None else ka[m.idx0]
        i1 = m.idx1 if kb is None else kb[m.idx1]
        return i0.astype(np.int64), i1.astype(np.int64)

    def describe(self, image_rgb: NDArray[np.uint8]) -> NDArray[np.float32]:
        return self.vpr.describe(image_rgb)


def load_bundle(
    cfg: ModelsConfig, extractor: str | None = None, matcher: str | None = None, vpr: str | None = None
) -> ModelBundle:
    """Load the configured models (names override the config); ModelError if one is missing."""
    return ModelBundle(
        load_extractor(extractor or cfg.extractor, cfg),
        load_matcher(matcher or cfg.matcher, cfg),
        load_place_recognizer(vpr or cfg.place_recognizer, cfg),
        cfg.match_max_keypoints,
    )


def check_map_models(topomap: TopoMap, bundle: ModelBundle) -> TopoMap:
    """Refuse a map built with other models; return it with features ready for the matcher."""
    if topomap.extractor and topomap.extractor != bundle.extractor.name:
        raise ModelError(
            f"the map's cached features come from {topomap.extractor!r} but the runtime uses "
            f"{bundle.extractor.name!r}: set models.extractor to match, or rebuild the map"
        )
    if topomap.vpr_model and topomap.vpr_model != bundle.vpr.name:
        raise ModelError(
            f"the map's place descriptors come from {topomap.vpr_model!r} but the runtime uses "
            f"{bundle.vpr.name!r}: set models.place_recognizer to match, or rebuild the map"
        )
    if topomap.vpr.shape[1] != bundle.vpr.dim:
        raise ModelError(f"map descriptors are {topomap.vpr.shape[1]}-d, the place recognizer gives {bundle.vpr.dim}-d")
    feats = topomap.features
    if isinstance(feats, FeatureStore):  # a loaded map: stay lazy (float16 on disk, converted per node on access)
        return dataclasses.replace(topomap, features=feats.mapped(as_features))
    return dataclasses.replace(topomap, features=[as_features(f) for f in feats])


class ExtractOnFirstCall:
    """An extract function whose model `load` builds on its first call: the second look's extractor
    (about 70 MB resident) stays unloaded for a camera no larger than the first look's input."""

    def __init__(self, load: Callable[[], FeatureExtractor]) -> None:
        self._load = load
        self._model: FeatureExtractor | None = None

    def __call__(self, image_rgb: NDArray[np.uint8]) -> Features:
        if self._model is None:
            self._model = self._load()
        return self._model.extract(image_rgb)


def second_look_for(topomap: TopoMap, models: ModelsConfig, params: LocalizationParams, bundle: ModelBundle,
                    clock: Clock = time.perf_counter) -> SecondLook | None:
    """The full-resolution second look on `topomap` where `params.second_look.candidates` > 0
    (its extractor at `models.second_look_size` / `second_look_keypoints`, loaded on the first
    look, the bundle's matcher over the strongest `models.second_look_match_keypoints` of them (0: all);
    ModelError naming the export command when that extractor is missing), else None."""
    if params.second_look.candidates <= 0:
        return None
    full = dataclasses.replace(models, extractor_size=models.second_look_size,
                               max_keypoints=models.second_look_keypoints)
    name = bundle.extractor.name
    check_extractor(name, full)  # a missing model fails here, not at the first look
    extract = ExtractOnFirstCall(lambda: load_extractor(name, full))
    strongest = dataclasses.replace(bundle, max_keypoints=models.second_look_match_keypoints)
    return SecondLook(topomap, params, extract, bundle.describe, strongest.match, models.extractor_size, clock)
