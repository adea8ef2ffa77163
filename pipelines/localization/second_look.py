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
points with map depth against the live depth image). Across a wide view change a right pose can
miss by 10-20 cm along the view and see through too: a pose that does is moved onto the live
depth (`depth_align`) and accepted where the move is small (`second_look_align_m`,
`second_look_align_deg`) and the moved pose keeps under half the see-through limit; its
covariance grows by the move.
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
from litevloc.pipelines.localization.depth_align import align_to_live_depth
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
        p = self.localizer.params
        points = keyframe_points(self.map, list(res.keyframes))
        why = sees_through_reason(points, res.T_map_camera, K, depth, p.second_look_max_see_through)
        if why and (moved := moved_onto_live_depth(res, points, K, depth, p)) is not None:
            return moved
        return res if not why else replace(res, accepted=False, T_map_camera=None, covariance=None, matches=None,
                                           reason=f"not localized: {why}", stop_reason=f"{res.stop_reason}; {why}")


def sees_through_reason(points_map: NDArray[np.float64], T_map_live: NDArray[np.float64], K: NDArray[np.float64],
                        depth: NDArray[np.floating], limit: float) -> str:
    """'' when at most `limit` of the (N, 3) map points the pose puts in the live depth's view lie
    in front of the live surface (see `see_through`), else the refusal reason; a pose it cannot
    check is refused; `limit` >= 1 checks nothing."""
    if limit >= 1.0:
        return ""
    n, share = see_through(points_map, T_map_live, K, depth)
    if n < MIN_CHECKED_POINTS:
        return (f"the pose puts {n} of its keyframes' map points in the live depth's view "
                f"(< {MIN_CHECKED_POINTS}): cannot check it against the live depth")
    if share > limit:
        return (f"the pose sees through the map: {share:.0%} of {n} keyframe points in view lie in front of "
                f"the live depth (> {limit:.0%})")
    return ""


def moved_onto_live_depth(res: LocalizationResult, points_map: NDArray[np.float64], K: NDArray[np.float64],
                          depth: NDArray[np.floating], p: LocalizationParams) -> LocalizationResult | None:
    """`res` with its pose moved onto the live depth (`align_to_live_depth` of its keyframes'
    (N, 3) map points) where the move is within `second_look_align_m` / `_deg` and the moved
    pose keeps under half of `second_look_max_see_through` in front of the live depth (it was
    fitted to that depth: what still lies in front counts against it), its covariance grown by
    the move; None otherwise."""
    if p.second_look_align_m <= 0 or res.T_map_camera is None:
        return None
    a = align_to_live_depth(points_map, res.T_map_camera, K, depth)
    if a is None or a.shift_m > p.second_look_align_m or a.shift_deg > p.second_look_align_deg:
        return None
    if sees_through_reason(points_map, a.T_map_live, K, depth, p.second_look_max_see_through / 2):
        return None
    cov = res.covariance
    if cov is not None:  # the pose is known no better than the move the live depth asked for
        cov = cov.copy()
        cov[:3, :3] += a.shift_m**2 * np.eye(3)
        cov[3:, 3:] += np.radians(a.shift_deg) ** 2 * np.eye(3)
    note = f"moved {a.shift_m:.2f} m / {a.shift_deg:.1f} deg onto the live depth ({a.pairs} points)"
    return replace(res, T_map_camera=a.T_map_live, covariance=cov, stop_reason=f"{res.stop_reason}; {note}")
