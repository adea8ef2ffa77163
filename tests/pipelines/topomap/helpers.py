"""Test doubles for the injected model callables (OpenCV ORB + thumbnails), no ONNX needed."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from litevloc.base.frames import parse_frames
from litevloc.base.params.mapping import MappingParams
from litevloc.config import load_config
from litevloc.hw.messages import GroundTruthPose, RgbdFrame
from litevloc.hw.streams.sevenscenes import SevenScenesSource
from litevloc.pipelines.topomap.build import MapBuilder, PosedFrame, build_two_pass
from litevloc.pipelines.topomap.types import TopoMap


@dataclass(frozen=True, eq=False)
class OrbFeatures:
    keypoints: NDArray[np.float32]
    descriptors: NDArray[np.uint8]
    scores: NDArray[np.float32]


def orb_extract(img: NDArray[np.uint8]) -> OrbFeatures:
    orb = cv2.ORB_create(nfeatures=800)
    kps, desc = orb.detectAndCompute(cv2.cvtColor(img, cv2.COLOR_RGB2GRAY), None)
    if desc is None:
        return OrbFeatures(np.zeros((0, 2), np.float32), np.zeros((0, 32), np.uint8), np.zeros(0, np.float32))
    return OrbFeatures(np.array([k.pt for k in kps], np.float32), desc, np.array([k.response for k in kps], np.float32))


def orb_match(a: OrbFeatures, b: OrbFeatures) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    if len(a.descriptors) == 0 or len(b.descriptors) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    ms = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True).match(a.descriptors, b.descriptors)
    return np.array([m.queryIdx for m in ms], np.int64), np.array([m.trainIdx for m in ms], np.int64)


def thumb_describe(img: NDArray[np.uint8]) -> NDArray[np.float32]:
    g = cv2.resize(cv2.cvtColor(img, cv2.COLOR_RGB2GRAY), (16, 12), interpolation=cv2.INTER_AREA).astype(np.float32)
    g = g.reshape(-1) - g.mean()
    return (g / (np.linalg.norm(g) + 1e-9)).astype(np.float32)


# the 7scenes preset's mapping: the hand-held Kinect's keyframe motion, height band and range
SEVEN_SCENES_MAPPING = load_config("7scenes").mapping


def seven_scenes_mapping(**keyframes: object) -> MappingParams:
    """The 7scenes preset's mapping with some keyframe settings changed."""
    kf = dataclasses.replace(SEVEN_SCENES_MAPPING.keyframes, **keyframes)  # type: ignore[arg-type]
    return dataclasses.replace(SEVEN_SCENES_MAPPING, keyframes=kf)


class _Built:
    """A finished two-pass build: `.finish()` returns the map, `.report` the build report."""

    def __init__(self, builder: MapBuilder, topomap: TopoMap) -> None:
        self.builder, self.report, self._map = builder, builder.report, topomap

    def finish(self) -> TopoMap:
        return self._map


def build_7scenes(folder: Path, frames: str, params: MappingParams) -> _Built:
    b = MapBuilder(params, orb_extract, thumb_describe, orb_match, "orb-test", "thumb-test")

    def posed(_need_color: bool) -> Iterator[PosedFrame]:
        pending: RgbdFrame | None = None
        for m in SevenScenesSource(folder, parse_frames(frames)):
            if isinstance(m, RgbdFrame):
                pending = m
            elif isinstance(m, GroundTruthPose) and pending is not None and pending.t_ns == m.t_ns:
                yield (pending.t_ns, pending.color, pending.depth, pending.K, m.T_world_camera, pending.index,
                       pending.color_jpeg)
                pending = None

    return _Built(b, build_two_pass(b, posed))
