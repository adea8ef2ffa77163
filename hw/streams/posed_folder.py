"""Shared machinery for posed RGB-D dataset folders (7-Scenes, TUM RGB-D).

A folder reader lists `FrameRecord`s (timestamp, image paths, ground-truth pose); this
module decodes them into `RgbdFrame` + `GroundTruthPose` messages with validation:
missing or corrupt images, depth of the wrong size and non-finite poses raise a
`StreamError` naming the file (strict mode), or are counted in `stats` and skipped
(`strict=False`, for live use).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from litevloc.hw.messages import (
    GroundTruthPose,
    Message,
    RgbdFrame,
    StreamError,
    StreamStats,
    decode_color,
    depth_from_units,
)
from litevloc.hw.streams.base import check_monotonic, select_indices


@dataclass(frozen=True)
class FrameRecord:
    """One frame of a posed folder dataset before decoding."""

    index: int
    t_ns: int
    color_path: Path
    depth_path: Path | None
    T_world_camera: NDArray[np.float64] | None


def read_color(path: Path) -> tuple[NDArray[np.uint8], bytes]:
    """Read and decode a colour image file -> (HxWx3 uint8 RGB, the file's bytes)."""
    if not path.is_file():
        raise StreamError(f"colour image missing: {path}")
    data = path.read_bytes()
    return decode_color(data, str(path)), data


def read_depth_raw(path: Path) -> NDArray[np.uint16]:
    """Decode a 16-bit depth PNG as stored (no scaling); StreamError if missing/corrupt."""
    if not path.is_file():
        raise StreamError(f"depth image missing: {path}")
    buf = np.fromfile(str(path), dtype=np.uint8)
    img = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED) if buf.size else None
    if img is None:
        raise StreamError(f"depth image is corrupt or not an image: {path}")
    if img.ndim != 2 or img.dtype != np.uint16:
        raise StreamError(f"depth image must be single-channel 16-bit, got {img.dtype} {img.shape}: {path}")
    return np.asarray(img, dtype=np.uint16)


def read_matrix_4x4(path: Path) -> NDArray[np.float64]:
    """Read a whitespace-separated 4x4 matrix text file; StreamError if malformed."""
    if not path.is_file():
        raise StreamError(f"pose file missing: {path}")
    try:
        M = np.loadtxt(str(path), dtype=np.float64)
    except ValueError as exc:
        raise StreamError(f"pose file is not a 4x4 matrix of numbers: {path}: {exc}") from exc
    if M.shape != (4, 4) or not np.all(np.isfinite(M)):
        raise StreamError(f"pose file must hold a finite 4x4 matrix, got shape {M.shape}: {path}")
    return M


class PosedFolderSource:
    """Decode `FrameRecord`s into messages (frame, then its ground-truth pose)."""

    def __init__(
        self,
        name: str,
        records: list[FrameRecord],
        K: NDArray[np.float64],
        depth_scale: float,
        frames: slice = slice(None),
        strict: bool = True,
    ) -> None:
        self.name = name
        self.stats = StreamStats()
        self.K = np.asarray(K, dtype=np.float64)
        self.depth_scale = float(depth_scale)  # stored units per metre
        self.strict = strict
        self.records = [records[i] for i in select_indices(len(records), frames)]

    def frame_count(self) -> int:
        return len(self.records)

    def ground_truth(self) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
        """(N,) times and (N,4,4) T_world_camera of the selected frames that have poses."""
        recs = [r for r in self.records if r.T_world_camera is not None]
        if not recs:
            return np.zeros(0, dtype=np.int64), np.zeros((0, 4, 4))
        return (
            np.array([r.t_ns for r in recs], dtype=np.int64),
            np.stack([r.T_world_camera for r in recs if r.T_world_camera is not None]),
        )

    def decode(self, rec: FrameRecord) -> RgbdFrame:
        """Decode one record into a validated frame (raises StreamError)."""
        color, data = read_color(rec.color_path)
        is_jpeg = data[:2] == b"\xff\xd8"
        depth = None
        if rec.depth_path is not None:
            raw = read_depth_raw(rec.depth_path)
            if raw.shape != color.shape[:2]:
                raise StreamError(
                    f"depth size {raw.shape[1]}x{raw.shape[0]} differs from colour size "
                    f"{color.shape[1]}x{color.shape[0]}: {rec.depth_path}"
                )
            depth = depth_from_units(raw, self.depth_scale)
        return RgbdFrame(
            t_ns=rec.t_ns, color=color, depth=depth, K=self.K, index=rec.index,
            color_jpeg=data if is_jpeg else None,
        )

    def __iter__(self) -> Iterator[Message]:
        prev: int | None = None
        for rec in self.records:
            check_monotonic(prev, rec.t_ns, f"{self.name} frame {rec.index}")
            prev = rec.t_ns
            try:
                frame = self.decode(rec)
            except StreamError as exc:
                if self.strict:
                    raise
                self.stats.skip(type(exc).__name__ + ": " + str(exc).split(":")[0])
                continue
            self.stats.messages += 1
            yield frame
            if rec.T_world_camera is not None:
                self.stats.messages += 1
                yield GroundTruthPose(rec.t_ns, rec.T_world_camera, index=rec.index)
