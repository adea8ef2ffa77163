"""The SLAM's feed from a recording (`runtime.tools.slam_build.run_on_messages`)."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from litevloc.hw.messages import EncodedRgbdFrame, StreamError
from litevloc.pipelines.slam.types import FrameRef
from litevloc.runtime.tools.slam_build import run_on_messages


class _Session:
    """Takes frames without loading them (as the front end does for frames between keyframes)."""

    def __init__(self) -> None:
        self.frames: list[FrameRef] = []

    def add_odometry(self, t_ns: int, T: Any) -> None:
        pass

    def add_frame(self, ref: FrameRef) -> None:
        self.frames.append(ref)

    def finish(self) -> str:
        return "result"


def test_a_frame_the_slam_never_loads_is_never_decoded() -> None:
    import cv2

    color = np.full((24, 32, 3), 90, np.uint8)
    good = cv2.imencode(".jpg", color)[1].tobytes()
    K, depth = np.eye(3), np.ones((24, 32), np.float32)
    frames = [EncodedRgbdFrame(1_000, b"\xff\xd8 not a jpeg", depth, K, index=0, where="frame 0"),
              EncodedRgbdFrame(2_000, good, depth, K, index=1)]
    session = _Session()
    sp = run_on_messages(session, frames)  # type: ignore[arg-type]
    assert sp.result == "result" and [r.index for r in session.frames] == [0, 1]
    img = session.frames[1].load()
    assert img.color.shape == (24, 32, 3) and img.jpeg == good and np.array_equal(img.depth, depth)
    with pytest.raises(StreamError, match="frame 0"):
        session.frames[0].load()
