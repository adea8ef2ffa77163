"""Pair RGB-D frames with their ground-truth poses from a message stream."""

from __future__ import annotations

from collections.abc import Iterable, Iterator

import numpy as np
from numpy.typing import NDArray

from litevloc.hw.messages import GroundTruthPose, Message, RgbdFrame


def posed_frames(
    messages: Iterable[Message], max_dt_ns: int = 1_000_000
) -> Iterator[tuple[RgbdFrame, NDArray[np.float64] | None]]:
    """Yield (frame, T_world_camera or None) in time order.

    A frame is paired with the ground-truth pose whose stamp is within `max_dt_ns` (the
    readers and recordings stamp both identically); odometry is ignored. A frame whose
    pose does not arrive before the next frame is yielded with None.
    """
    pending: RgbdFrame | None = None
    last_gt: GroundTruthPose | None = None
    for m in messages:
        if isinstance(m, RgbdFrame):
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
