"""The full-resolution second look: a refused GL or LL query verified again on denser features.

Across a 25-30 deg view change the default features (the map's stored keypoints, extracted at
240x320) leave too few correspondences for PnP's inlier floor, or weak ones whose pose is off.
The second look extracts features at a higher resolution (`models.second_look_size`,
`second_look_keypoints`) from the query and from the candidate keyframes' stored images (on first
use, kept in a bounded cache) and runs the same verification on them, GL's or LL's (PnP gates,
joint refinement, distinctiveness, the prior's gate): GL's and LL's strategies over a view of the
map whose features are these, without the pooled pass and without a look after this one. The view
has no keypoint depth (the map's depth belongs to its stored keypoints), so only the live depth
lifts points.

Before LightGlue runs on a candidate at full resolution, a cheap pre-check (`checks.look_precheck`:
mutual nearest neighbours of the two full-resolution feature sets + PnP with the live depth, no model)
drops a candidate that shares too little with the query (`second_look.precheck_min_inliers`).

Denser features also let a wrong pose collect more inliers (a band of repeated leaflets): a pose
the second look accepts must not see through the map (`checks.see_through`: the keyframes' stored
points with map depth against the live depth image).
"""

from __future__ import annotations

import time
from collections import OrderedDict
from collections.abc import Iterator, Sequence
from dataclasses import replace
from typing import overload

import cv2
import numpy as np
from numpy.typing import NDArray

from litevloc.base.params.localization import LocalizationParams
from litevloc.pipelines.localization.checks.look_precheck import precheck_inliers
from litevloc.pipelines.localization.checks.see_through import checked_against_live_depth
from litevloc.pipelines.localization.global_search import GlobalSearch
from litevloc.pipelines.localization.local_search import LocalSearch
from litevloc.pipelines.localization.prior import Prior
from litevloc.pipelines.localization.query import Clock, MatchFn
from litevloc.pipelines.localization.refusals import QueryRefusal
from litevloc.pipelines.localization.results import CandidateAttempt, LocalizationResult
from litevloc.pipelines.localization.verifier import CandidateVerifier, DescribeFn, ExtractFn
from litevloc.pipelines.pnp import Refusal
from litevloc.pipelines.topomap.types import FeatureSet, TopoMap


class StoredImageFeatures(Sequence[FeatureSet]):
    """Per node: `extract` of the node's stored JPEG image (RGB), made on first access; the last
    `capacity` nodes' features are kept (least recently used dropped first). No keypoint depth:
    the map's belongs to its stored keypoints."""

    has_keypoint_depth = False  # read by `TopoMap.keypoint_depth`

    def __init__(self, images_jpeg: Sequence[bytes], extract: ExtractFn, capacity: int = 64) -> None:
        if capacity < 1:
            raise ValueError(f"capacity must be >= 1, got {capacity}")
        self.images_jpeg, self.extract, self.capacity = images_jpeg, extract, capacity
        self._cache: OrderedDict[int, FeatureSet] = OrderedDict()
        self.extracted = 0  # extractions so far (cache misses)

    def __len__(self) -> int:
        return len(self.images_jpeg)

    @overload
    def __getitem__(self, i: int) -> FeatureSet: ...

    @overload
    def __getitem__(self, i: slice) -> list[FeatureSet]: ...

    def __getitem__(self, i: int | slice) -> FeatureSet | list[FeatureSet]:
        if isinstance(i, slice):
            return [self._node(k) for k in range(*i.indices(len(self)))]
        return self._node(int(i))

    def __iter__(self) -> Iterator[FeatureSet]:
        return (self._node(k) for k in range(len(self)))

    def _node(self, k: int) -> FeatureSet:
        if not 0 <= k < len(self):
            raise IndexError(f"node {k} out of range (0..{len(self) - 1})")
        if k in self._cache:
            self._cache.move_to_end(k)
            return self._cache[k]
        bgr = cv2.imdecode(np.frombuffer(self.images_jpeg[k], np.uint8), cv2.IMREAD_COLOR)
        if bgr is None:
            raise ValueError(f"keyframe {k}'s stored image does not decode as JPEG")
        feats = self.extract(np.ascontiguousarray(bgr[:, :, ::-1]))
        self.extracted += 1
        self._cache[k] = feats
        if len(self._cache) > self.capacity:
            self._cache.popitem(last=False)
        return feats


class LastImageExtract:
    """`extract` that keeps its last image's features: the pre-check and the verification of one
    query share one extraction (the image object itself is the key, held until the next call)."""

    def __init__(self, extract: ExtractFn) -> None:
        self.extract = extract
        self._last: tuple[NDArray[np.uint8], FeatureSet] | None = None

    def __call__(self, image_rgb: NDArray[np.uint8]) -> FeatureSet:
        if self._last is None or self._last[0] is not image_rgb:
            self._last = (image_rgb, self.extract(image_rgb))
        return self._last[1]


class SecondLook:
    """GL's or LL's verification of chosen nodes on features at a higher resolution (see the module).

    `extract` and `match` are the higher-resolution extractor and a matcher over all its
    keypoints; `describe` the map's place recognizer (the attempts' similarities);
    `first_size` (h, w) the first look's extractor input: an image no larger has nothing finer
    to show, and is not looked at again."""

    def __init__(self, topomap: TopoMap, params: LocalizationParams, extract: ExtractFn, describe: DescribeFn,
                 match: MatchFn, first_size: tuple[int, int], clock: Clock = time.perf_counter,
                 capacity: int = 64) -> None:
        if len(topomap.images_jpeg) != topomap.n_nodes:
            raise ValueError(f"the second look needs every keyframe's stored image: the map has "
                             f"{len(topomap.images_jpeg)} for {topomap.n_nodes} keyframes")
        self.map = topomap  # its stored keypoints and their map depth: the see-through check
        self.first_size = first_size  # (h, w) pixels the first look's extractor sees
        self.clock = clock
        self.extract = LastImageExtract(extract)  # the query's: the pre-check's and the verification's
        self.features = StoredImageFeatures(topomap.images_jpeg, extract, capacity)
        view = replace(topomap, features=self.features)
        # denser features also make wrong poses near a tracked one: LL's look stays closer to its prior
        radius = min(params.prior_gate.radius_m, params.second_look.prior_gate_m)
        # and its guided matches keep the global-mutual rule whatever LL's first look does: over 2048
        # keypoints the best pair within the radius is too often another keypoint's (b8066da)
        self.params = replace(params, prior_gate=replace(params.prior_gate, radius_m=radius),
                              local_search=replace(params.local_search, guided_global_mutual=True))
        # no look after this one, and no pooled pass (denser features need no pooling of weak candidates)
        verifier = CandidateVerifier(view, self.extract, describe, match, clock)
        self.local = LocalSearch(verifier, second_look=None, pooling=False)
        self.global_ = GlobalSearch(self.local, second_look=None, pooling=False)

    def __call__(self, t_ns: int, color: NDArray[np.uint8], depth: NDArray[np.float32] | None,
                 K: NDArray[np.float64], nodes: Sequence[int], prior: Prior | None = None,
                 local: bool = False) -> LocalizationResult | None:
        """GL on `nodes` only, in that order, at the higher resolution (`prior` as for
        `GlobalSearch.localize`), or LL from `prior` (`local`, `LocalSearch.localize`), the
        accepted pose checked against the live depth (`checks.see_through`); None for an image
        no larger than `first_size`."""
        if color.shape[0] <= self.first_size[0] and color.shape[1] <= self.first_size[1]:
            return None
        refused: tuple[CandidateAttempt, ...] = ()
        pre_ms = 0.0
        if self.params.second_look.precheck_min_inliers > 0 and depth is not None:
            t0 = self.clock()
            nodes, refused = self.prechecked(color, depth, K, nodes)
            pre_ms = (self.clock() - t0) * 1e3
            if not nodes:
                return LocalizationResult(t_ns, "local" if local else "global", False,
                                          "no candidate passed the full-resolution pre-check", attempts=refused,
                                          timings_ms={"precheck": pre_ms, "total": pre_ms},
                                          refusal=QueryRefusal.NO_CANDIDATE)
        if not local:
            res = self.global_.localize(t_ns, color, depth, K, self.params, prior, only=nodes)
        else:
            if prior is None:
                raise ValueError("a local second look needs the prior")
            res = self.local.localize(t_ns, color, depth, K, self.params, prior, only=nodes)
        if pre_ms > 0:  # the pre-check's time and refusals belong to this look
            ms = dict(res.timings_ms)
            ms["precheck"], ms["total"] = pre_ms, ms.get("total", 0.0) + pre_ms
            res = replace(res, attempts=refused + res.attempts, timings_ms=ms)
        return checked_against_live_depth(self.map, res, K, depth, self.params)

    def prechecked(self, color: NDArray[np.uint8], depth: NDArray[np.float32], K: NDArray[np.float64],
                   nodes: Sequence[int]) -> tuple[list[int], tuple[CandidateAttempt, ...]]:
        """`nodes` whose full-resolution mutual nearest neighbours with the query reach
        `second_look.precheck_min_inliers` PnP inliers (`checks.look_precheck`), in order, and
        the refused ones' attempts."""
        live = self.extract(color)
        floor = self.params.second_look.precheck_min_inliers
        kept: list[int] = []
        refused: list[CandidateAttempt] = []
        for n in nodes:
            mnn, inl = precheck_inliers(live, depth, K, self.features[n], self.map.K[n], self.params)
            if inl >= floor:
                kept.append(int(n))
            else:
                refused.append(CandidateAttempt(int(n), float("nan"), mnn, inl, f"full-resolution pre-check: "
                                                f"{inl} PnP inliers of {mnn} mutual nearest neighbours (< {floor})",
                                                Refusal.INLIERS))
        return kept, tuple(refused)
