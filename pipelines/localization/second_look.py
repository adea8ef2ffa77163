"""The full-resolution second look: a refused GL or LL query verified again on denser features.

Across a 25-30 deg view change the default features (the map's stored keypoints, extracted at
240x320) leave too few correspondences for PnP's inlier floor, or weak ones whose pose is off.
The second look extracts features at a higher resolution (`models.second_look_size`,
`second_look_keypoints`) from the query and from the candidate keyframes' stored images (on first
use, kept in a bounded cache) and runs the same verification on them, GL's or LL's (PnP gates,
joint refinement, distinctiveness, the prior's gate): a `VisualLocalizer` over a view of the map
whose features are these, without the pooled pass. The view has no keypoint depth (the map's
depth belongs to its stored keypoints), so only the live depth lifts points.

Denser features also let a wrong pose collect more inliers (a band of repeated leaflets): a pose
the second look accepts must not see through the map (`see_through`: the keyframes' stored
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
from litevloc.pipelines.localization.query import Clock, MatchFn
from litevloc.pipelines.localization.results import LocalizationResult
from litevloc.pipelines.localization.see_through import keyframe_points, see_through
from litevloc.pipelines.localization.vloc import DescribeFn, ExtractFn, VisualLocalizer
from litevloc.pipelines.topomap.types import FeatureSet, TopoMap

MIN_CHECKED_POINTS = 20  # map points in view with live depth, below which the see-through check cannot tell


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
        self.features = StoredImageFeatures(topomap.images_jpeg, extract, capacity)
        view = replace(topomap, features=self.features)
        # denser features also make wrong poses near a tracked one: LL's look stays closer to its prior
        inner = replace(params, second_look_candidates=0, pooled_min_inliers=0,
                        prior_gate_m=min(params.prior_gate_m, params.second_look_prior_gate_m))
        self.localizer = VisualLocalizer(view, inner, extract, describe, match, clock)

    def __call__(
        self, t_ns: int, color: NDArray[np.uint8], depth: NDArray[np.float32] | None, K: NDArray[np.float64],
        nodes: Sequence[int], prior_T_map_camera: NDArray[np.float64] | None = None, prior_age_s: float = 0.0,
        prior_cov: NDArray[np.float64] | None = None, prior_travel_m: float | None = None,
        local_fused: bool | None = None,
    ) -> LocalizationResult | None:
        """GL on `nodes` only, in that order, at the higher resolution (prior as for
        `VisualLocalizer.localize_global`), or LL from the prior where `local_fused` says whether
        it is fusion's (`localize_local`); None for an image no larger than `first_size`."""
        if color.shape[0] <= self.first_size[0] and color.shape[1] <= self.first_size[1]:
            return None
        if local_fused is None:
            res = self.localizer.localize_global(t_ns, color, depth, K, prior_T_map_camera, prior_age_s,
                                                 prior_cov=prior_cov, prior_travel_m=prior_travel_m, only=nodes)
        else:
            if prior_T_map_camera is None:
                raise ValueError("a local second look needs the prior")
            res = self.localizer.localize_local(t_ns, color, depth, K, prior_T_map_camera, prior_age_s, local_fused,
                                                prior_cov, prior_travel_m, only=nodes)
        if not res.accepted or res.T_map_camera is None or depth is None:
            return res
        why = self._sees_through(res.T_map_camera, K, depth, list(res.keyframes))
        return res if not why else replace(res, accepted=False, T_map_camera=None, covariance=None, matches=None,
                                           reason=f"not localized: {why}", stop_reason=f"{res.stop_reason}; {why}")

    def _sees_through(self, T_map_live: NDArray[np.float64], K: NDArray[np.float64], depth: NDArray[np.float32],
                      nodes: list[int]) -> str:
        """'' when the pose keeps the keyframes' map points off the live free space (see
        `see_through`), else the refusal reason; a pose it cannot check is refused."""
        limit = self.localizer.params.second_look_max_see_through
        if limit >= 1.0:
            return ""
        n, share = see_through(keyframe_points(self.map, nodes), T_map_live, K, depth)
        if n < MIN_CHECKED_POINTS:
            return (f"the pose puts {n} of its keyframes' map points in the live depth's view "
                    f"(< {MIN_CHECKED_POINTS}): cannot check it against the live depth")
        if share > limit:
            return (f"the pose sees through the map: {share:.0%} of {n} keyframe points in view lie in front of "
                    f"the live depth (> {limit:.0%})")
        return ""
