"""Update a map from a whole new session (`litevloc map update`): align the session to the map,
turn its frames into observations and feed them to `update.MapUpdate`.

A posed session (its own trajectory, in its own frame): every `align_every`-th frame is
localized, the session's frame is aligned to the map robustly (`merge.robust_alignment`, as
`map merge` aligns sessions), and every frame is then posed through that alignment: new places
get poses too, and no frame needs global localization. An unposed session: every frame is
localized by the localizer's state machine. Either way a frame is compared with the map only
after the camera moved by the mapping pre-filter's motion since the last compared frame.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Generic, TypeVar

import cv2
import numpy as np
from numpy.typing import NDArray

from litevloc.base.geometry import backproject_depth, invert, relative_pose_error
from litevloc.base.params.mapping import MappingParams
from litevloc.models.types import Features
from litevloc.pipelines.depth_lookup import depth_at
from litevloc.pipelines.localization.prior import Prior
from litevloc.pipelines.localization.vloc import VisualLocalizer
from litevloc.pipelines.topomap.graphs import MatchFn
from litevloc.pipelines.topomap.keyframes import moved
from litevloc.pipelines.topomap.merge import robust_alignment
from litevloc.pipelines.topomap.types import NodeFeatures, TopoMap
from litevloc.pipelines.topomap.update import MapUpdate, Observation, UpdateReport

F64 = NDArray[np.float64]
_Out = TypeVar("_Out")


@dataclass(frozen=True, eq=False)
class SessionFrame:
    """One frame of the new session."""

    t_ns: int
    index: int
    color: NDArray[np.uint8]  # HxWx3 RGB
    depth: NDArray[np.float32] | None  # HxW metres, NaN = invalid
    K: F64  # 3x3
    jpeg: bytes | None  # the source's own JPEG of `color`, stored as it is
    T_session_camera: F64 | None  # 4x4 pose in the session's own frame (None: unposed)


@dataclass
class SessionUpdate:
    """What `update_from_session` made and counted."""

    new_map: TopoMap
    report: UpdateReport
    frames: int = 0
    compared: int = 0
    skipped_not_moved: int = 0
    posed_session_aligned_by: int = 0  # localized frames consistent with the session alignment
    localization_errors_m: list[float] = field(default_factory=list)  # unposed sessions with ground truth


class OncePerImage(Generic[_Out]):
    """`fn(image)` computed once per image object: a frame's features and VPR descriptor serve its
    localization and its observation (the same arrays)."""

    def __init__(self, fn: Callable[[NDArray[np.uint8]], _Out]) -> None:
        self._fn = fn
        self._image: NDArray[np.uint8] | None = None  # held, so its identity cannot be reused
        self._out: _Out | None = None

    def __call__(self, image: NDArray[np.uint8]) -> _Out:
        if image is not self._image or self._out is None:
            self._out = self._fn(image)
            self._image = image
        return self._out


def align_session(frames: Iterable[SessionFrame], localizer: VisualLocalizer, params: MappingParams
                  ) -> tuple[F64 | None, int]:
    """(T_map_session, localized frames consistent with it) of a posed session; (None, 0) when no
    frame localized. Raises `MapMergeError` when the localized frames do not agree."""
    up = params.update
    estimates: list[F64] = []
    at: list[F64] = []
    weights: list[int] = []
    for f in frames:
        if f.T_session_camera is None or f.index % up.align_every:
            continue
        res = localizer.process(f.t_ns, f.color, f.depth, f.K)
        if res.accepted and res.T_map_camera is not None:
            estimates.append(res.T_map_camera @ invert(f.T_session_camera))
            at.append(f.T_session_camera)
            weights.append(res.n_inliers)
            if len(estimates) >= up.align_frames:
                break
    if not estimates:
        return None, 0
    al = robust_alignment(estimates, at, weights, params.merge, what="localized session frames")
    return al.T_A_B, int(al.consistent.sum())


def observation(f: SessionFrame, T_map_camera: F64, feats: Features, vpr: NDArray[np.float32],
                params: MappingParams, localization_inliers: int = 0) -> Observation:
    """A frame with its map pose as `MapUpdate` takes it: keypoint depth, JPEG, depth points."""
    if f.depth is None:
        raise ValueError(f"frame {f.index} has no depth")
    kp = params.keyframes
    pts_cam, _ = backproject_depth(f.depth, f.K, stride=kp.pixel_stride)
    pts_cam = pts_cam[pts_cam[:, 2] <= kp.max_depth_m]
    jpeg = f.jpeg
    if jpeg is None:
        ok, enc = cv2.imencode(".jpg", f.color[:, :, ::-1], [cv2.IMWRITE_JPEG_QUALITY, params.jpeg_quality])
        if not ok:
            raise ValueError(f"JPEG encoding of frame {f.index} failed")
        jpeg = enc.tobytes()
    h, w = f.color.shape[:2]
    kp_depth = depth_at(f.depth, feats.keypoints, params.depth)
    T = T_map_camera
    return Observation(
        t_ns=f.t_ns, index=f.index, T_map_camera=T, K=np.asarray(f.K, np.float64), image_size=(w, h),
        features=NodeFeatures(np.asarray(feats.keypoints, np.float32), np.asarray(feats.descriptors),
                              np.asarray(feats.scores, np.float32), (w, h), kp_depth),
        keypoint_depth=kp_depth, vpr=np.asarray(vpr, np.float32), jpeg=jpeg,
        points_map=(pts_cam[::4] @ T[:3, :3].T + T[:3, 3]).astype(np.float32),
        localization_inliers=localization_inliers,
    )


def update_from_session(
    topomap: TopoMap, frames: Callable[[], Iterable[SessionFrame]], localizer: VisualLocalizer,
    extract: Callable[[NDArray[np.uint8]], Features], describe: Callable[[NDArray[np.uint8]], NDArray[np.float32]],
    match: MatchFn, params: MappingParams, every: int = 1, on_frame: Callable[[], None] | None = None,
) -> SessionUpdate:
    """The updated map of `topomap` from a session (see the module docstring).

    `frames()` opens the session (twice for a posed one: alignment, then update); `extract` and
    `describe` should be `OncePerImage`-wrapped with the ones `localizer` uses, so a frame's
    features are computed once. Raises ValueError when no frame could be compared with the map."""
    T_map_session, aligned = align_session(frames(), localizer, params)
    upd = MapUpdate(topomap, match, params.update, params.keyframes)
    out = SessionUpdate(topomap, upd.report, posed_session_aligned_by=aligned)
    last_T: F64 | None = None
    for f in frames():
        if on_frame is not None:
            on_frame()
        out.frames += 1
        if f.depth is None or f.index % every:
            continue
        inliers = 0
        localize: Callable[[], int] | None = None
        if T_map_session is not None:
            if f.T_session_camera is None:
                continue
            T = T_map_session @ f.T_session_camera

            def localize(f: SessionFrame = f, T_prior: F64 = T) -> int:
                res = localizer.localize_local(f.t_ns, f.color, f.depth, f.K, Prior(T_prior, fused=False))
                return res.n_inliers if res.accepted else 0
        else:  # the localizer tracks every frame; only frames that moved are compared
            res = localizer.process(f.t_ns, f.color, f.depth, f.K)
            if not res.accepted or res.T_map_camera is None:
                continue
            T, inliers = res.T_map_camera, res.n_inliers
            if f.T_session_camera is not None:
                out.localization_errors_m.append(float(relative_pose_error(T, f.T_session_camera)[0]))
        if last_T is not None and not moved(last_T, T, params.keyframes):
            out.skipped_not_moved += 1
            continue
        last_T = T
        out.compared += 1
        upd.observe(observation(f, T, extract(f.color), describe(f.color), params, inliers), localize)
    if out.compared == 0:
        raise ValueError("no frame localized against the map; nothing to update from")
    out.new_map, out.report = upd.finish(params.covisibility, params.connectivity, params.occupancy)
    return out
