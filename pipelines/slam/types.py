"""Data of the mapping pass's SLAM: frames as the front end sees them, keyframes, graph edges.

Frames: `T_a_b` maps points of frame b into frame a; camera poses are of the camera optical
frame; covariances of edges are 6x6 over a right perturbation of the measured `T_a_b` in
GTSAM's tangent order (rotation vector first, then translation; radians, metres).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from litevloc.pipelines.keypoint_alignment import AlignmentView
from litevloc.pipelines.topomap.types import FeatureSet

F64 = NDArray[np.float64]
ExtractFn = Callable[[NDArray[np.uint8]], FeatureSet]
DescribeFn = Callable[[NDArray[np.uint8]], NDArray[np.float32]]
MatchFn = Callable[[FeatureSet, FeatureSet], tuple[NDArray[np.int64], NDArray[np.int64]]]
EdgeKind = Literal["odometry", "visual", "loop", "planar"]


@dataclass(frozen=True, eq=False)
class FrameImages:
    """The images of one frame: colour HxWx3 uint8 RGB, depth HxW float32 metres (NaN =
    invalid), and the source's JPEG bytes of the colour when it had them."""

    color: NDArray[np.uint8]
    depth: NDArray[np.float32]
    jpeg: bytes | None = None


@dataclass(frozen=True, eq=False)
class FrameRef:
    """A frame the front end may look at: stamp (ns), source index, 3x3 intrinsics and how to
    get its images (`load()`; decoded or rendered on demand, so frames the front end skips cost
    nothing)."""

    t_ns: int
    index: int
    K: F64
    load: Callable[[], FrameImages]


@dataclass(frozen=True)
class SlamModels:
    """The model callables the SLAM runs: local features, place descriptor, the cheap matcher
    of visual edges and tracking, and the localizer's matcher that verifies loops."""

    extract: ExtractFn
    describe: DescribeFn
    match_vo: MatchFn
    match_loop: MatchFn


@dataclass(eq=False)
class Keyframe:
    """One SLAM keyframe.

    features: its local features with `depth` (N,) at each keypoint (NaN = none);
    points: (N, 3) keypoints lifted with that depth (camera frame, NaN rows without depth);
    vpr: place descriptor (of the raw colour image; the map keeps it for its keyframes);
    cloud: (M, 3) strided depth points (camera frame) for the map's occupancy and coverage;
    odom: (odometry segment, 4x4 T_odom_base) at its stamp, None where the odometry had none;
    T_init: 4x4 initial T_map_camera (chained edges); chain: id of its chain of odometry and
    visual edges (a new chain starts where neither reaches the previous keyframe);
    path_m: distance travelled along its chain from the chain's first keyframe (metres, from the
    initial poses); path_var_t: its edges' translation variances accumulated along the chain
    from there (m^2, per step the most certain edge into the keyframe, its largest axis);
    view: its images for keypoint alignment while visual edges can still reach it, else None.
    """

    id: int
    index: int
    t_ns: int
    K: F64
    size: tuple[int, int]
    features: Any
    points: F64
    vpr: NDArray[np.float32]
    jpeg: bytes
    cloud: NDArray[np.float32]
    odom: tuple[int, F64] | None
    T_init: F64
    chain: int
    path_m: float = 0.0
    path_var_t: float = 0.0
    view: AlignmentView | None = None


@dataclass(frozen=True, eq=False)
class Edge:
    """A pose-graph edge between keyframes `a` and `b`: the measured `T_a_b` (4x4) and its 6x6
    covariance (see the module docstring); `inliers`/`similarity` of visual and loop edges."""

    a: int
    b: int
    T_a_b: F64
    covariance: F64
    kind: EdgeKind
    inliers: int = 0
    similarity: float = float("nan")


@dataclass
class FrameRecord:
    """How a frame is related to the keyframe before it: `anchor` keyframe id and
    `T_anchor_frame` (camera to camera), from odometry (`how` "odometry") or visual tracking
    ("visual"); None for frames posed later by interpolation between their neighbours.
    `keyframe`: the keyframe id when the frame became one (its relation then is the one it
    had before, used to spread the increments' error between two keyframes)."""

    index: int
    t_ns: int
    anchor: int | None = None
    T_anchor_frame: F64 | None = None
    how: str = ""
    keyframe: int | None = None


@dataclass
class LoopAttempt:
    """One verified-or-not loop candidate (for the report)."""

    query: int
    candidate: int
    similarity: float
    accepted: bool
    reason: str
    inliers: int = 0


@dataclass
class Fault:
    """Something in the recording that the SLAM had to work around, and what it did."""

    kind: str
    t_s: float
    detail: str
    handling: str = ""

    def as_dict(self) -> dict[str, Any]:
        return {"kind": self.kind, "t_s": round(self.t_s, 3), "detail": self.detail, "handling": self.handling}


@dataclass
class Timings:
    """Wall seconds per part of the pass."""

    front_end: float = 0.0
    loop_search: float = 0.0
    optimisation: float = 0.0
    extra: dict[str, float] = field(default_factory=dict)
