"""A pose for every frame: from the optimised keyframes, or from an external trajectory.

`frame_poses`: a keyframe takes its optimised pose. A frame between keyframes a and b that
the front end related to a (odometry or tracking, `T_a_f`) is predicted forward from a and
backward from b through b's own relation to a, and the two are blended by time, so the
trajectory meets both keyframes' optimised poses and the error of the short odometry or
tracking increment is spread over the stretch. Frames without a relation (not tracked
frames of a camera-only pass) are interpolated in time between the posed frames around
them. Frames whose keyframes were left out of the map get None.

`interpolate_trajectory`: an external trajectory (e.g. a TUM file from another SLAM) at the
frame stamps; frames outside it, or between two of its poses further apart than
`max_gap_ns`, get None (callers count and skip them).
"""

from __future__ import annotations

import bisect

import numpy as np
from numpy.typing import NDArray

from litevloc.base.geometry import interpolate_pose, invert
from litevloc.pipelines.slam.types import F64, FrameRecord


def _blend(recs: list[FrameRecord], k: int, poses: dict[int, F64], next_kf: dict[int, int],
           kf_t: dict[int, int]) -> F64 | None:
    """Pose of non-keyframe `recs[k]` from its anchor keyframe (and the next keyframe, if it
    is related to the same anchor)."""
    r = recs[k]
    if r.anchor is None or r.anchor not in poses or r.T_anchor_frame is None:
        return None
    fwd = poses[r.anchor] @ r.T_anchor_frame
    j = next_kf.get(k)
    if j is None:
        return fwd
    b = recs[j]
    if b.anchor != r.anchor or b.T_anchor_frame is None or b.keyframe not in poses:
        return fwd
    assert b.keyframe is not None
    a_rec_t = kf_t.get(r.anchor)
    if a_rec_t is None or b.t_ns <= a_rec_t:
        return fwd
    back = poses[b.keyframe] @ invert(b.T_anchor_frame) @ r.T_anchor_frame
    s = (r.t_ns - a_rec_t) / (b.t_ns - a_rec_t)
    return interpolate_pose(fwd, back, float(np.clip(s, 0.0, 1.0)))


def frame_poses(recs: list[FrameRecord], poses: dict[int, F64]) -> list[F64 | None]:
    """4x4 T_map_camera (or None) for each frame record, in order (see the module docstring)."""
    next_kf: dict[int, int] = {}
    nxt: int | None = None
    for k in range(len(recs) - 1, -1, -1):
        if nxt is not None:
            next_kf[k] = nxt
        if recs[k].keyframe is not None:
            nxt = k
    kf_t = {r.keyframe: r.t_ns for r in recs if r.keyframe is not None}
    out: list[F64 | None] = []
    for k, r in enumerate(recs):
        if r.keyframe is not None:
            out.append(poses.get(r.keyframe))
        else:
            out.append(_blend(recs, k, poses, next_kf, kf_t))
    return _fill_by_time(recs, out)


def _fill_by_time(recs: list[FrameRecord], out: list[F64 | None]) -> list[F64 | None]:
    """Frames with no relation to a keyframe: interpolated between the posed frames around them,
    when both exist and belong to the map."""
    posed = [k for k, T in enumerate(out) if T is not None]
    for k, r in enumerate(recs):
        if out[k] is not None or r.anchor is not None:
            continue
        i = bisect.bisect_left(posed, k)
        if i == 0 or i == len(posed):
            continue
        a, b = posed[i - 1], posed[i]
        Ta, Tb = out[a], out[b]
        assert Ta is not None and Tb is not None
        s = (r.t_ns - recs[a].t_ns) / max(recs[b].t_ns - recs[a].t_ns, 1)
        out[k] = interpolate_pose(Ta, Tb, float(s))
    return out


def interpolate_trajectory(times_ns: NDArray[np.int64], poses: NDArray[np.float64], stamps_ns: list[int],
                           max_gap_ns: int) -> list[F64 | None]:
    """Poses (N, 4, 4) at sorted `times_ns`, interpolated at each stamp (None outside the
    trajectory or inside a gap longer than `max_gap_ns`)."""
    t = np.asarray(times_ns, np.int64)
    out: list[F64 | None] = []
    for s in stamps_ns:
        if len(t) == 0 or s < t[0] or s > t[-1]:
            out.append(None)
            continue
        i = int(np.searchsorted(t, s, side="left"))
        if t[i] == s:
            out.append(np.asarray(poses[i], np.float64).copy())
            continue
        if t[i] - t[i - 1] > max_gap_ns:
            out.append(None)
            continue
        out.append(interpolate_pose(poses[i - 1], poses[i], (s - t[i - 1]) / (t[i] - t[i - 1])))
    return out
