"""Build a `TopoMap` from a posed RGB-D stream, in two streaming passes.

Pass 1 (`MapBuilder.add` per posed frame, geometry only): the motion pre-filter runs
online; a candidate keeps only its pose and its compact coverage keys
(`keyframes.coverage_keys_sliced`, a few KB), and its depth points go into a voxel
count accumulator for the occupancy grid (bounded by the mapped volume, not by the
recording's length). No image is decoded for the models and no network runs here.

`select()` then picks the keyframes (greedy coverage; the count follows from the
coverage target, `budget` is an optional cap reported in `BuildReport.budget_bound`).

Pass 2 (`MapBuilder.attach` for the selected frames only, `wanted()` names them):
JPEG bytes, local features with the depth at each keypoint, and the VPR descriptor.
So model inference runs once per keyframe rather than once per candidate, and peak
memory holds the keyframes' data plus the bounded accumulators. `build_two_pass` runs
both passes over a re-iterable source. `finish()` builds the grid and both graphs.

A source that already lifted a frame's depth and ran the models (the mapping pass's SLAM,
`pipelines.slam`) feeds `add_points` and `attach_features` instead of `add` and `attach`: the
same map, without decoding or running anything twice.

Nothing here reads files or knows models: feature extraction, matching and place
description are injected callables, frames come from an injected iterable.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

import cv2
import numpy as np
from numpy.typing import NDArray

from litevloc.base.geometry import backproject_depth, check_rigid, rotation_angle, transform_points
from litevloc.base.params.mapping import KeyframeParams, MappingParams
from litevloc.pipelines.depth_lookup import depth_at
from litevloc.pipelines.topomap.graphs import (
    MatchFn,
    build_connectivity,
    build_covisibility,
    covisibility_candidates,
)
from litevloc.pipelines.topomap.keyframes import (
    band_keys,
    budget_binds,
    coverage_keys_sliced,
    greedy_select,
    moved,
)
from litevloc.pipelines.topomap.occupancy import build_occupancy
from litevloc.pipelines.topomap.types import FeatureSet, NodeFeatures, TopoMap

ExtractFn = Callable[[NDArray[np.uint8]], FeatureSet]
DescribeFn = Callable[[NDArray[np.uint8]], NDArray[np.float32]]


@dataclass(eq=False)
class _Candidate:
    frame_pos: int
    index: int
    t_ns: int
    T: NDArray[np.float64]
    K: NDArray[np.float64]
    size: tuple[int, int]
    keys: NDArray[np.int64]  # coverage_keys_sliced of its depth points
    # pass 2, keyframes only:
    jpeg: bytes | None = None
    features: NodeFeatures | None = None
    kp_depth: NDArray[np.float32] | None = None
    vpr: NDArray[np.float32] | None = None


class _VoxelCounts:
    """Point counts per voxel of a fixed lattice (plane cells of `cell` m x height slices of
    `dz` m), merged in batches: memory grows with the mapped volume, not with the points."""

    def __init__(self, axes: NDArray[np.float64], up: NDArray[np.float64], cell: float, dz: float) -> None:
        self.axes, self.up, self.cell, self.dz = axes, up, float(cell), float(dz)
        self.keys = np.zeros((0, 3), np.int32)
        self.counts = np.zeros(0, np.int64)
        self._pending: list[NDArray[np.int32]] = []
        self._n_pending = 0

    def add(self, points: NDArray[np.float64]) -> None:
        q = np.empty((len(points), 3), np.int32)
        q[:, :2] = np.floor(points @ self.axes.T / self.cell)
        q[:, 2] = np.floor(points @ self.up / self.dz)
        self._pending.append(q)
        self._n_pending += len(q)
        if self._n_pending > 2_000_000:
            self._merge()

    def _merge(self) -> None:
        if not self._pending:
            return
        allk = np.concatenate([self.keys, *self._pending])
        allc = np.concatenate([self.counts, np.ones(self._n_pending, np.int64)])
        self.keys, inv = np.unique(allk, axis=0, return_inverse=True)
        self.counts = np.bincount(inv.reshape(-1), weights=allc, minlength=len(self.keys)).astype(np.int64)
        self._pending, self._n_pending = [], 0

    def points(self, max_repeat: int) -> NDArray[np.float64]:
        """Voxel centres, each repeated min(count, max_repeat) times, (N, 3) map frame."""
        self._merge()
        rep = np.minimum(self.counts, max_repeat)
        k = np.repeat(self.keys, rep, axis=0).astype(np.float64)
        return ((k[:, :2] + 0.5) * self.cell) @ self.axes + ((k[:, 2:] + 0.5) * self.dz) * self.up

    @property
    def nbytes(self) -> int:
        return int(self.keys.nbytes + self.counts.nbytes + sum(p.nbytes for p in self._pending))


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
    budget: int | None = None  # the explicit cap, if any
    budget_bound: bool = False  # the cap stopped the selection before the coverage target
    candidate_key_bytes: int = 0  # memory held per pass-1 candidate (coverage keys), total
    voxel_bytes: int = 0  # occupancy accumulator


def strongest_index(scores: NDArray[np.floating], n: int) -> NDArray[np.intp] | None:
    """Indices of the `n` highest scores in their original order; None when all are kept (n = 0
    or no more than n)."""
    if n <= 0 or len(scores) <= n:
        return None
    return np.sort(np.argsort(-np.asarray(scores), kind="stable")[:n])


def candidate_points(depth: NDArray[np.float32], K: NDArray[np.float64], kp: KeyframeParams) -> NDArray[np.float64]:
    """(N, 3) camera-frame points of a depth image that pass 1 keeps for a candidate (every
    `kp.pixel_stride`-th pixel, up to `kp.max_depth_m`)."""
    pts_cam, _ = backproject_depth(depth, K, stride=kp.pixel_stride)
    return pts_cam[pts_cam[:, 2] <= kp.max_depth_m]


def encode_jpeg(color: NDArray[np.uint8], quality: int, what: str) -> bytes:
    """JPEG bytes of an RGB image (OpenCV); RuntimeError naming `what` if encoding fails."""
    ok, enc = cv2.imencode(".jpg", color[:, :, ::-1], [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:
        raise RuntimeError(f"JPEG encoding of {what} failed")
    return bytes(enc.tobytes())


class MapBuilder:
    """Two streaming passes over posed frames (see module docstring), then `finish()`."""

    def __init__(
        self, params: MappingParams, extract: ExtractFn, describe: DescribeFn, match: MatchFn,
        extractor_name: str, vpr_name: str,
    ) -> None:
        from litevloc.pipelines.topomap.keyframes import plane_axes

        self.params = params
        self.extract, self.describe, self.match = extract, describe, match
        self.extractor_name, self.vpr_name = extractor_name, vpr_name
        self.up = np.asarray(params.up, dtype=np.float64) / np.linalg.norm(params.up)
        self.trajectory: list[NDArray[np.float64]] = []
        self.candidates: list[_Candidate] = []
        self.report = BuildReport(budget=params.keyframes.budget)
        r = params.occupancy.resolution_m
        self._voxels = _VoxelCounts(plane_axes(self.up), self.up, r / 2, 0.05)
        self._selected: list[int] | None = None
        self._cells: dict[tuple[int, ...], list[int]] = {}

    def _skip(self, reason: str) -> None:
        self.report.skipped[reason] = self.report.skipped.get(reason, 0) + 1

    def _is_candidate(self, T: NDArray[np.float64]) -> bool:
        """Motion pre-filter against the last candidate, and no near-duplicate of ANY earlier
        candidate (closer than both motion thresholds): revisiting a mapped place adds no
        candidates, so pass-1 memory follows the place, not the recording's length."""
        if not self.candidates:
            return True
        kp = self.params.keyframes
        min_rot = np.radians(kp.min_rotation_deg)
        if not moved(self.candidates[-1].T, T, kp):
            return False
        if kp.min_translation_m <= 0:
            return True
        c = tuple(np.floor(T[:3, 3] / kp.min_translation_m).astype(int))
        for dx in (-1, 0, 1):
            for dy in (-1, 0, 1):
                for dz in (-1, 0, 1):
                    for j in self._cells.get((c[0] + dx, c[1] + dy, c[2] + dz), ()):
                        o = self.candidates[j].T
                        if (np.linalg.norm(T[:3, 3] - o[:3, 3]) < kp.min_translation_m
                                and rotation_angle(o[:3, :3].T @ T[:3, :3]) < min_rot):
                            self._skip("revisit (near-duplicate candidate)")
                            return False
        return True

    def is_candidate(self, T_map_camera: NDArray[np.float64]) -> bool:
        """Would a frame at this pose pass the motion pre-filter (no side effects)? Lets a
        source that renders or decodes depth on demand skip it for every other frame
        (then `add_pose`)."""
        return self._is_candidate(np.asarray(T_map_camera, np.float64))

    def add_pose(self, T_map_camera: NDArray[np.float64], index: int) -> None:
        """Pass 1 for a frame that `is_candidate` rejected: only its camera position is kept
        (trajectory for occupancy and connectivity)."""
        self.report.frames += 1
        T = check_rigid(T_map_camera, f"pose of frame {index}", atol=1e-4)
        self.trajectory.append(T[:3, 3].copy())

    def _index_candidate(self, pos: int) -> None:
        kp = self.params.keyframes
        if kp.min_translation_m > 0:
            c = tuple(np.floor(self.candidates[pos].T[:3, 3] / kp.min_translation_m).astype(int))
            self._cells.setdefault(c, []).append(pos)

    def add(
        self, t_ns: int, color: NDArray[np.uint8] | None, depth: NDArray[np.float32] | None,
        K: NDArray[np.float64], T_map_camera: NDArray[np.float64], index: int, jpeg: bytes | None = None,
    ) -> bool:
        """Pass 1: add one posed frame (geometry only; `color`/`jpeg` unused, may be None).

        `color` gives the image size when present; otherwise it is taken from the depth.
        Returns True if the frame became a keyframe candidate.
        """
        if depth is None:
            self.report.frames += 1
            check_rigid(T_map_camera, f"pose of frame {index}", atol=1e-4)
            self._skip("no depth")
            return False
        h, w = (color if color is not None else depth).shape[:2]
        return self.add_points(t_ns, candidate_points(depth, K, self.params.keyframes), (w, h), K, T_map_camera,
                               index)

    def add_points(
        self, t_ns: int, pts_cam: NDArray[np.float64], size: tuple[int, int], K: NDArray[np.float64],
        T_map_camera: NDArray[np.float64], index: int,
    ) -> bool:
        """Pass 1 for a frame whose depth is already lifted (`candidate_points`, camera frame):
        `add` without the depth image (`size` = (width, height) of the image). A source that
        kept only these points (the SLAM front end) feeds its keyframes here."""
        self.report.frames += 1
        T = check_rigid(T_map_camera, f"pose of frame {index}", atol=1e-4)
        self.trajectory.append(T[:3, 3].copy())
        if not self._is_candidate(T):
            return False
        if len(pts_cam) < 50:
            self._skip("too little valid depth")
            return False
        pts = transform_points(T, pts_cam)
        self._voxels.add(pts)
        keys = coverage_keys_sliced(pts, T[:3, 3], self.up, self.params.keyframes)
        self.candidates.append(_Candidate(
            frame_pos=len(self.trajectory) - 1, index=index, t_ns=t_ns, T=T, K=np.asarray(K, np.float64),
            size=(int(size[0]), int(size[1])), keys=keys,
        ))
        self._index_candidate(len(self.candidates) - 1)
        self.report.candidates += 1
        self.report.candidate_key_bytes += int(keys.nbytes)
        return True

    def n_covisibility_pairs(self, selected: list[int]) -> int:
        T = np.stack([self.candidates[i].T for i in selected])
        return len(covisibility_candidates(T, self.params.covisibility))

    def select(self) -> list[int]:
        """Candidate positions chosen as keyframes, in time order (cached after the first call)."""
        if self._selected is not None:
            return self._selected
        if not self.candidates:
            raise ValueError("no usable frames: every frame lacked a pose or valid depth")
        traj = np.asarray(self.trajectory)
        ref = float(np.median(traj @ self.up))
        kp = self.params.keyframes
        cover = [band_keys(c.keys, ref, kp) for c in self.candidates]
        chosen, hist = greedy_select(cover, kp)
        self.report.coverage_history = hist
        self.report.coverage = hist[-1] if hist else 0.0
        self.report.budget_bound = budget_binds(len(chosen), hist, kp)
        self._selected = sorted(chosen)
        return self._selected

    def wanted(self) -> dict[int, int]:
        """Pass 2: frame index -> candidate position of every selected keyframe."""
        return {self.candidates[i].index: i for i in self.select()}

    def attach(self, pos: int, color: NDArray[np.uint8], depth: NDArray[np.float32],
               jpeg: bytes | None = None) -> None:
        """Pass 2: image data of selected candidate `pos` (features, keypoint depth, VPR, JPEG)."""
        c = self.candidates[pos]
        feats = self.extract(color)
        kp_depth = depth_at(depth, np.asarray(feats.keypoints), self.params.depth)
        if jpeg is None:
            jpeg = encode_jpeg(color, self.params.jpeg_quality, f"frame {c.index}")
        h, w = color.shape[:2]
        self.attach_features(pos, feats, kp_depth, np.asarray(self.describe(color), np.float32), jpeg, (w, h))

    def attach_features(self, pos: int, feats: FeatureSet, kp_depth: NDArray[np.float32], vpr: NDArray[np.float32],
                        jpeg: bytes, size: tuple[int, int]) -> None:
        """Pass 2 with the models already run (`attach` without the images): local features of
        the candidate's image (size = (width, height)), the depth at each keypoint (mapping.depth),
        its VPR descriptor and JPEG bytes. The strongest `stored_keypoints` are kept."""
        c = self.candidates[pos]
        if tuple(size) != c.size:
            raise ValueError(f"frame {c.index}: pass 2 image is {size[0]}x{size[1]}, "
                             f"pass 1 saw {c.size[0]}x{c.size[1]}")
        keep = strongest_index(np.asarray(feats.scores), self.params.stored_keypoints)
        rows = slice(None) if keep is None else keep
        z = np.asarray(kp_depth, np.float32)[rows]
        c.kp_depth = z
        c.jpeg = jpeg
        c.features = NodeFeatures(np.asarray(feats.keypoints, np.float32)[rows], np.asarray(feats.descriptors)[rows],
                                  np.asarray(feats.scores, np.float32)[rows], c.size, z)
        c.vpr = np.asarray(vpr, np.float32)

    def finish(self, on_pair: Callable[[], None] | None = None, selected: list[int] | None = None) -> TopoMap:
        """Build the grid and both graphs over the selected keyframes (all must be attached)."""
        sel = self.select() if selected is None else selected
        nodes = [self.candidates[i] for i in sel]
        missing = [c.index for c in nodes if c.features is None]
        if missing:
            raise ValueError(f"pass 2 never delivered keyframe frame(s) {missing[:5]} (source changed between passes?)")
        self.report.keyframes = len(nodes)
        traj = np.asarray(self.trajectory)
        cloud = self._voxels.points(self.params.occupancy.min_points)
        self.report.voxel_bytes = self._voxels.nbytes
        grid = build_occupancy(cloud, traj, self.up, self.params.occupancy)
        T = np.stack([c.T for c in nodes])
        K = np.stack([c.K for c in nodes])
        feats = [c.features for c in nodes if c.features is not None]
        kpd = [c.kp_depth for c in nodes if c.kp_depth is not None]
        ce, ci, cw = build_covisibility(T, K, feats, kpd, self.match, self.params.covisibility, on_pair)
        self.report.covisibility_pairs_checked = len(covisibility_candidates(T, self.params.covisibility))
        ne, nm = build_connectivity(np.array([c.frame_pos for c in nodes]), traj, grid, self.params.connectivity)
        return TopoMap(
            T_map_camera=T, K=K, image_size=np.array([c.size for c in nodes], dtype=np.int32),
            t_ns=np.array([c.t_ns for c in nodes], dtype=np.int64),
            frame_index=np.array([c.index for c in nodes], dtype=np.int64),
            vpr=np.stack([c.vpr for c in nodes if c.vpr is not None]).astype(np.float32), features=feats,
            images_jpeg=[c.jpeg for c in nodes if c.jpeg is not None], covis_edges=ce, covis_inliers=ci,
            covis_weight=cw, conn_edges=ne, conn_metres=nm, grid=grid, extractor=self.extractor_name,
            vpr_model=self.vpr_name,
        )


PosedFrame = tuple[int, "NDArray[np.uint8] | None", "NDArray[np.float32] | None", NDArray[np.float64],
                   NDArray[np.float64], int, "bytes | None"]


def build_two_pass(
    builder: MapBuilder, frames: Callable[[bool], Iterable[PosedFrame]],
    on_frame: Callable[[], None] | None = None, on_pair: Callable[[], None] | None = None,
) -> TopoMap:
    """Run both passes: `frames(need_color)` opens the posed source anew each call and yields
    (t_ns, color, depth, K, T_map_camera, index, jpeg); pass 1 calls it with False (colour may
    then be None: sources can skip decoding), pass 2 with True."""
    for t, color, depth, K, T, idx, jpeg in frames(False):
        builder.add(t, color, depth, K, T, idx, jpeg)
        if on_frame is not None:
            on_frame()
    want = builder.wanted()
    for _t, color, depth, _K, _T, idx, jpeg in frames(True):
        pos = want.get(idx)
        if pos is None or builder.candidates[pos].features is not None:
            continue
        if color is None or depth is None:
            raise ValueError(f"frame {idx}: pass 2 needs its colour and depth")
        builder.attach(pos, color, depth, jpeg)
    return builder.finish(on_pair)
