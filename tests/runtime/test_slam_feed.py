"""`feed_builder`: the SLAM's keyframes go to the map builder with their features; a selected
keyframe that has no place descriptor (not a loop-search keyframe) is described from its JPEG."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from litevloc.base.geometry import make_T
from litevloc.pipelines.slam.graph import GraphResult
from litevloc.pipelines.slam.session import SlamResult
from litevloc.pipelines.slam.types import FrameRecord, Keyframe
from litevloc.pipelines.topomap.build import encode_jpeg
from litevloc.pipelines.topomap.types import NodeFeatures
from litevloc.runtime.slam_build import feed_builder

K = np.array([[50.0, 0.0, 16.0], [0.0, 50.0, 12.0], [0.0, 0.0, 1.0]])


def _keyframe(i: int, vpr: NDArray[np.float32] | None, color: NDArray[np.uint8]) -> Keyframe:
    feats = NodeFeatures(np.zeros((0, 2), np.float32), np.zeros((0, 8), np.float32), np.zeros(0, np.float32),
                         (32, 24), np.zeros(0, np.float32))
    return Keyframe(i, 10 * i, 10 * i, K, (32, 24), feats, np.zeros((0, 3)), vpr, encode_jpeg(color, 95, "test"),
                    np.ones((60, 3), np.float32), None, np.eye(4), 0)


class _Builder:
    """The map builder's double: every keyframe selected; records what is attached and described."""

    def __init__(self) -> None:
        self.candidates: list[Any] = []
        self.attached: dict[int, NDArray[np.float32]] = {}
        self.described: list[NDArray[np.uint8]] = []

    def add_pose(self, T: Any, index: int) -> None:
        raise AssertionError("every frame here is a keyframe")

    def add_points(self, t_ns: int, pts: Any, size: Any, K: Any, T: Any, index: int) -> bool:
        self.candidates.append(type("C", (), {"index": index})())
        return True

    def select(self) -> list[int]:
        return list(range(len(self.candidates)))

    def describe(self, color: NDArray[np.uint8]) -> NDArray[np.float32]:
        self.described.append(color)
        return np.full(4, float(color.mean()), np.float32)

    def attach_features(self, pos: int, feats: Any, depth: Any, vpr: NDArray[np.float32], jpeg: bytes,
                        size: Any) -> None:
        self.attached[pos] = vpr


def test_a_keyframe_without_place_descriptor_is_described_from_its_jpeg() -> None:
    grey = np.full((24, 32, 3), 200, np.uint8)
    kfs = [_keyframe(0, np.ones(4, np.float32), grey), _keyframe(1, None, grey)]
    poses = {k.id: make_T(np.eye(3), np.array([k.id, 0.0, 0.0])) for k in kfs}
    frames = [FrameRecord(k.index, k.t_ns, keyframe=k.id) for k in kfs]
    res = SlamResult(kfs, [], GraphResult(poses, [], []), frames, [poses[0], poses[1]], np.eye(4))
    b = _Builder()
    assert feed_builder(res, b) == 0  # type: ignore[arg-type]
    assert len(b.described) == 1 and b.described[0].shape == (24, 32, 3)
    assert np.allclose(b.attached[0], 1.0) and abs(float(b.attached[1][0]) - 200.0) < 2.0
