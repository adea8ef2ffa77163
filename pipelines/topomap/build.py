"""Build a `TopoMap` from a posed RGB-D stream.

Streaming in one pass (`MapBuilder.add` per posed frame), then `finish()`:
the motion pre-filter runs online, so only candidates keep data (JPEG bytes, cached
local features with the depth at each keypoint, the VPR descriptor, a subsampled point
cloud for coverage and occupancy). Nothing here reads files or knows models: feature
extraction, matching and place description are injected callables.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import cv2
import numpy as np
from numpy.typing import NDArray

from litevloc.pipelines.depth_lookup import DepthLookupParams, depth_at
from litevloc.pipelines.geometry import backproject_depth, check_rigid, rotation_angle, transform_points
from litevloc.pipelines.topomap.graphs import (
    ConnectivityParams,
    CovisibilityParams,
    MatchFn,
    build_connectivity,
    build_covisibility,
    covisibility_candidates,
)
from litevloc.pipelines.topomap.keyframes import KeyframeParams, coverage_keys, greedy_select
from litevloc.pipelines.topomap.occupancy import OccupancyParams, build_occupancy
from litevloc.pipelines.topomap.types import FeatureSet, NodeFeatures, TopoMap

ExtractFn = Callable[[NDArray[np.uint8]], FeatureSet]
DescribeFn = Callable[[NDArray[np.uint8]], NDArray[np.float32]]


@dataclass(frozen=True)
class MappingParams:
    """All map-building parameters. `up` is the unit up vector of the map frame.

    `covisibility_matcher` names the matcher the caller should inject for covisibility
    verification (mutual-NN by default: PnP-RANSAC verification makes the cheap matcher
    good enough, and it is ~100x faster than LightGlue over all keyframe pairs).
    """

    up: tuple[float, float, float] = (0.0, 0.0, 1.0)
    covisibility_matcher: str = "mnn"
    keyframes: KeyframeParams = field(default_factory=KeyframeParams)
    occupancy: OccupancyParams = field(default_factory=OccupancyParams)
    covisibility: CovisibilityParams = field(default_factory=CovisibilityParams)
    connectivity: ConnectivityParams = field(default_factory=ConnectivityParams)
    depth: DepthLookupParams = field(default_factory=DepthLookupParams)
    jpeg_quality: int = 90

    def __post_init__(self) -> None:
        n = float(np.linalg.norm(self.up))
        if not np.isfinite(n) or n < 1e-6:
            raise ValueError(f"up must be a non-zero vector, got {self.up}")
        if not (1 <= self.jpeg_quality <= 100):
            raise ValueError("jpeg_quality must be in [1, 100]")


@dataclass(eq=False)
class _Candidate:
    frame_pos: int
    index: int
    t_ns: int
    T: NDArray[np.float64]
    K: NDArray[np.float64]
    size: tuple[int, int]
    jpeg: bytes
    features: NodeFeatures
    kp_depth: NDArray[np.float32]
    vpr: NDArray[np.float32]
    points: NDArray[np.float32]  # (P, 3) map frame, subsampled


@dataclass
class BuildReport:
    """What happened during a build (for the CLI summary and benchmarks)."""

    frames: int = 0
    candidates: int = 0
    keyframes: int = 0
    coverage: float = 0.0
    coverage_history: list[float] = field(default_factory=list)
    covisibility_pairs_checked: int = 0
    skipped: dict[str, int] = field(default_factory=dict)


class MapBuilder:
    """Accumulate posed frames, then `finish()` into a TopoMap."""

    def __init__(
        self, params: MappingParams, extract: ExtractFn, describe: DescribeFn, match: MatchFn,
        extractor_name: str, vpr_name: str,
    ) -> None:
        self.params = params
        self.extract, self.describe, self.match = extract, describe, match
        self.extractor_name, self.vpr_name = extractor_name, vpr_name
        self.up = np.asarray(params.up, dtype=np.float64) / np.linalg.norm(params.up)
        self.trajectory: list[NDArray[np.float64]] = []
        self.candidates: list[_Candidate] = []
        self.report = BuildReport()

    def _skip(self, reason: str) -> None:
        self.report.skipped[reason] = self.report.skipped.get(reason, 0) + 1

    def _is_candidate(self, T: NDArray[np.float64]) -> bool:
        if not self.candidates:
            return True
        last = self.candidates[-1].T
        kp = self.params.keyframes
        return bool(
            np.linalg.norm(T[:3, 3] - last[:3, 3]) >= kp.min_translation_m
            or rotation_angle(last[:3, :3].T @ T[:3, :3]) >= np.radians(kp.min_rotation_deg)
        )

    def add(
        self, t_ns: int, color: NDArray[np.uint8], depth: NDArray[np.float32] | None, K: NDArray[np.float64],
        T_map_camera: NDArray[np.float64], index: int, jpeg: bytes | None = None,
    ) -> bool:
        """Add one posed frame; returns True if it became a keyframe candidate."""
        self.report.frames += 1
        T = check_rigid(T_map_camera, f"pose of frame {index}", atol=1e-4)
        if depth is None:
            self._skip("no depth")
            return False
        self.trajectory.append(T[:3, 3].copy())
        if not self._is_candidate(T):
            return False
        kp = self.params.keyframes
        pts_cam, _ = backproject_depth(depth, K, stride=kp.pixel_stride)
        pts_cam = pts_cam[pts_cam[:, 2] <= kp.max_depth_m]
        if len(pts_cam) < 50:
            self._skip("too little valid depth")
            return False
        feats = self.extract(color)
        kp_depth = depth_at(depth, feats.keypoints, self.params.depth)
        if jpeg is None:
            ok, enc = cv2.imencode(".jpg", color[:, :, ::-1], [cv2.IMWRITE_JPEG_QUALITY, self.params.jpeg_quality])
            if not ok:
                raise RuntimeError(f"JPEG encoding of frame {index} failed")
            jpeg = enc.tobytes()
        h, w = color.shape[:2]
        self.candidates.append(_Candidate(
            frame_pos=len(self.trajectory) - 1, index=index, t_ns=t_ns, T=T, K=np.asarray(K, np.float64), size=(w, h),
            jpeg=jpeg,
            features=NodeFeatures(np.asarray(feats.keypoints, np.float32), np.asarray(feats.descriptors),
                                  np.asarray(feats.scores, np.float32), (w, h)),
            kp_depth=kp_depth, vpr=np.asarray(self.describe(color), np.float32),
            points=transform_points(T, pts_cam).astype(np.float32),
        ))
        self.report.candidates += 1
        return True

    def n_covisibility_pairs(self, selected: list[int]) -> int:
        T = np.stack([self.candidates[i].T for i in selected])
        return len(covisibility_candidates(T, self.params.covisibility))

    def select(self) -> list[int]:
        """Candidate positions chosen as keyframes, in time order."""
        if not self.candidates:
            raise ValueError("no usable frames: every frame lacked a pose or valid depth")
        traj = np.asarray(self.trajectory)
        ref = float(np.median(traj @ self.up))
        cover = [coverage_keys(c.points.astype(np.float64), c.T[:3, 3], self.up, ref, self.params.keyframes)
                 for c in self.candidates]
        chosen, hist = greedy_select(cover, self.params.keyframes)
        self.report.coverage_history = hist
        self.report.coverage = hist[-1] if hist else 0.0
        return sorted(chosen)

    def finish(self, on_pair: Callable[[], None] | None = None, selected: list[int] | None = None) -> TopoMap:
        """Select keyframes, build the grid and both graphs."""
        sel = self.select() if selected is None else selected
        nodes = [self.candidates[i] for i in sel]
        self.report.keyframes = len(nodes)
        traj = np.asarray(self.trajectory)
        cloud = np.concatenate([c.points for c in self.candidates]).astype(np.float64)
        grid = build_occupancy(cloud, traj, self.up, self.params.occupancy)
        T = np.stack([c.T for c in nodes])
        K = np.stack([c.K for c in nodes])
        feats = [c.features for c in nodes]
        ce, ci, cw = build_covisibility(T, K, feats, [c.kp_depth for c in nodes], self.match,
                                        self.params.covisibility, on_pair)
        self.report.covisibility_pairs_checked = len(covisibility_candidates(T, self.params.covisibility))
        ne, nm = build_connectivity(np.array([c.frame_pos for c in nodes]), traj, grid, self.params.connectivity)
        return TopoMap(
            T_map_camera=T, K=K, image_size=np.array([c.size for c in nodes], dtype=np.int32),
            t_ns=np.array([c.t_ns for c in nodes], dtype=np.int64),
            frame_index=np.array([c.index for c in nodes], dtype=np.int64),
            vpr=np.stack([c.vpr for c in nodes]).astype(np.float32), features=feats,
            images_jpeg=[c.jpeg for c in nodes], covis_edges=ce, covis_inliers=ci, covis_weight=cw,
            conn_edges=ne, conn_metres=nm, grid=grid, extractor=self.extractor_name, vpr_model=self.vpr_name,
        )
