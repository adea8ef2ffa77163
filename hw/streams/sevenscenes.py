"""Reader for the Microsoft 7-Scenes folder format.

Files per frame `frame-NNNNNN`: `.color.jpg` (640x480 RGB), `.depth.png` (uint16 mm,
0 invalid), `.pose.txt` (4x4 T_world_camera). `camera-intrinsics.txt` (3x3 K) if
present, else the published fx = fy = 585, cx = 320, cy = 240.

7-Scenes has no timestamps: frames are assumed at **30 Hz** (Kinect v1 rate), so frame i
has `t_ns = i * 1e9 / 30` (rounded to ns). The colour and depth cameras are not
registered; the same intrinsics are used for both (a few cm of systematic error).

The published pose matrices are not exactly orthonormal (rotation blocks deviate from
SO(3) by up to ~1e-4). They are projected onto SO(3) (nearest rotation, SVD) on read, so
every pose is a proper rigid transform and survives quaternion round trips exactly.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from litevloc.hw.messages import StreamError
from litevloc.hw.streams.posed_folder import FrameRecord, PosedFolderSource, read_matrix_4x4
from litevloc.pipelines.geometry import project_to_so3

FPS = 30.0
DEFAULT_K = np.array([[585.0, 0.0, 320.0], [0.0, 585.0, 240.0], [0.0, 0.0, 1.0]])
_FRAME_RE = re.compile(r"^frame-(\d{6})\.color\.(jpg|png)$")


def is_sevenscenes_folder(path: Path) -> bool:
    return path.is_dir() and any(_FRAME_RE.match(p.name) for p in path.iterdir())


def read_intrinsics(folder: Path) -> np.ndarray:
    f = folder / "camera-intrinsics.txt"
    if not f.exists():
        return DEFAULT_K.copy()
    try:
        K = np.loadtxt(str(f), dtype=np.float64)
    except ValueError as exc:
        raise StreamError(f"{f}: not a 3x3 matrix of numbers: {exc}") from exc
    if K.shape != (3, 3) or not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise StreamError(f"{f}: must hold a valid 3x3 intrinsics matrix, got {K.tolist()}")
    return K


class SevenScenesSource(PosedFolderSource):
    """A 7-Scenes sequence folder as a stream of RgbdFrame + GroundTruthPose."""

    def __init__(self, folder: str | Path, frames: slice = slice(None), strict: bool = True) -> None:
        root = Path(folder)
        if not root.is_dir():
            raise StreamError(f"7-Scenes folder not found: {root}")
        matches = [m for p in root.iterdir() if (m := _FRAME_RE.match(p.name))]
        if not matches:
            raise StreamError(f"no frame-NNNNNN.color.jpg files in {root}: not a 7-Scenes folder")
        records = []
        pose_problems: list[str] = []
        for m in sorted(matches, key=lambda m: int(m.group(1))):
            idx = int(m.group(1))
            stem = root / f"frame-{m.group(1)}"
            try:
                T = read_matrix_4x4(Path(f"{stem}.pose.txt"))
                T[:3, :3] = project_to_so3(T[:3, :3])
            except StreamError as exc:
                if strict:
                    raise
                pose_problems.append(f"ground-truth pose unreadable: {exc}")
                T = None
            records.append(
                FrameRecord(
                    index=idx,
                    t_ns=round(idx * 1e9 / FPS),
                    color_path=root / m.group(0),
                    depth_path=Path(f"{stem}.depth.png"),
                    T_world_camera=T,
                )
            )
        super().__init__(f"7scenes:{root.name}", records, read_intrinsics(root), 1000.0, frames, strict)
        for reason in pose_problems:
            self.stats.skip(reason.split(":")[0])
