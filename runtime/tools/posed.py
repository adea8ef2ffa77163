"""Pair RGB-D frames with poses from a message stream: the ground truth, the odometry, or a
trajectory (`litevloc map build --poses`)."""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable, Iterator
from typing import overload

import numpy as np
from numpy.typing import NDArray

from litevloc.base.geometry import interpolate_pose
from litevloc.hw.messages import EncodedRgbdFrame, GroundTruthPose, Message, Odometry, RgbdFrame, SourceMessage
from litevloc.pipelines.slam.frames import interpolate_trajectory

Pose = NDArray[np.float64]
# `frame_type=EncodedRgbdFrame` pairs frames whose colour is still encoded
# (`McapSource.messages(defer_color=True)`): a consumer that needs a few frames' colour decodes those.
Posed = Iterator[tuple[RgbdFrame, Pose | None]]
PosedEncoded = Iterator[tuple[EncodedRgbdFrame, Pose | None]]
PosedAny = Iterator[tuple[RgbdFrame | EncodedRgbdFrame, Pose | None]]
FrameType = type[RgbdFrame] | type[EncodedRgbdFrame]

@overload
def posed_frames(messages: Iterable[Message], max_dt_ns: int = ...) -> Posed: ...


@overload
def posed_frames(
    messages: Iterable[SourceMessage], max_dt_ns: int = ..., *, frame_type: type[EncodedRgbdFrame],
) -> PosedEncoded: ...


def posed_frames(
    messages: Iterable[SourceMessage], max_dt_ns: int = 1_000_000, *,
    frame_type: FrameType = RgbdFrame,
) -> PosedAny:
    """Yield (frame, T_world_camera or None) in time order; frames are the messages of `frame_type`.

    A frame is paired with the ground-truth pose whose stamp is within `max_dt_ns` (the
    readers and recordings stamp both identically); odometry is ignored. A frame whose
    pose does not arrive before the next frame is yielded with None.
    """
    pending: RgbdFrame | EncodedRgbdFrame | None = None
    last_gt: GroundTruthPose | None = None
    for m in messages:
        if isinstance(m, frame_type):
            if pending is not None:
                yield pending, None
            pending = m
            if last_gt is not None and abs(last_gt.t_ns - m.t_ns) <= max_dt_ns:
                yield m, last_gt.T_world_camera
                pending = None
        elif isinstance(m, GroundTruthPose):
            last_gt = m
            if pending is not None and abs(m.t_ns - pending.t_ns) <= max_dt_ns:
                yield pending, m.T_world_camera
                pending = None
    if pending is not None:
        yield pending, None


@overload
def odometry_posed_frames(messages: Iterable[Message], T_base_camera: Pose) -> Posed: ...


@overload
def odometry_posed_frames(
    messages: Iterable[SourceMessage], T_base_camera: Pose, *, frame_type: type[EncodedRgbdFrame],
) -> PosedEncoded: ...


def odometry_posed_frames(
    messages: Iterable[SourceMessage], T_base_camera: Pose, *,
    frame_type: FrameType = RgbdFrame,
) -> PosedAny:
    """Yield (frame, T_odom_camera or None) in time order: the recording's odometry of base_link
    interpolated at each frame stamp and moved to the camera (`T_base_camera`), as the odometry
    says (gaps and jumps included: the honest no-loop baseline). A frame waits for the first
    odometry sample at or after its stamp; frames before the first sample or after the last
    get None. Ground truth is ignored."""
    pending: deque[RgbdFrame | EncodedRgbdFrame] = deque()
    last: Odometry | None = None
    for m in messages:
        if isinstance(m, Odometry):
            while pending and pending[0].t_ns <= m.t_ns:
                f = pending.popleft()
                yield f, None if last is None else _between(last, m, f.t_ns) @ T_base_camera
            last = m
        elif isinstance(m, frame_type):
            if last is not None and m.t_ns == last.t_ns:
                yield m, last.T_odom_base @ T_base_camera
            else:
                pending.append(m)
    for f in pending:
        yield f, None


def _between(a: Odometry, b: Odometry, t_ns: int) -> Pose:
    s = 0.0 if b.t_ns == a.t_ns else (t_ns - a.t_ns) / (b.t_ns - a.t_ns)
    return interpolate_pose(a.T_odom_base, b.T_odom_base, float(np.clip(s, 0.0, 1.0)))


@overload
def trajectory_posed_frames(
    messages: Iterable[Message], times_ns: NDArray[np.int64], poses: Pose, max_gap_ns: int,
) -> Posed: ...


@overload
def trajectory_posed_frames(
    messages: Iterable[SourceMessage], times_ns: NDArray[np.int64], poses: Pose, max_gap_ns: int, *,
    frame_type: type[EncodedRgbdFrame],
) -> PosedEncoded: ...


def trajectory_posed_frames(
    messages: Iterable[SourceMessage], times_ns: NDArray[np.int64], poses: Pose, max_gap_ns: int,
    *, frame_type: FrameType = RgbdFrame,
) -> PosedAny:
    """Yield (frame, T_world_camera or None): a trajectory (sorted (N,) ns stamps, (N, 4, 4) camera
    poses, e.g. from an external SLAM's TUM file) interpolated at each frame stamp; None outside
    it or between two of its poses more than `max_gap_ns` apart. Other messages are ignored."""
    for m in messages:
        if isinstance(m, frame_type):
            yield m, interpolate_trajectory(times_ns, poses, [m.t_ns], max_gap_ns)[0]
