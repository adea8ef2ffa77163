"""Reader for the Microsoft 7-Scenes folder format.

Files per frame `frame-NNNNNN`: `.color.jpg` (640x480 RGB), `.depth.png` (uint16 mm,
0 invalid), `.pose.txt` (4x4 T_world_camera). `camera-intrinsics.txt` (3x3 K) if
present, else the published fx = fy = 585, cx = 320, cy = 240.

7-Scenes has no timestamps: frames are assumed at **30 Hz** (Kinect v1 rate), so frame i
has `t_ns = i * 1e9 / 30` (rounded to ns).

Colour/depth registration. The published intrinsics are the DEPTH camera's, the depth
images are in the depth camera, and the ground-truth poses (KinectFusion on depth) are
depth-camera poses; the colour camera has other intrinsics and sits a few cm away.
* Without a calibration (`K_color=None`, the default, as older recordings): frames carry
  the published K for both images and the raw depth (a few cm / ~2 deg of systematic error).
* With a calibration (`K_color`, `T_color_depth`, e.g. from `litevloc calib` and the
  `rgbd_calibration` block of config/presets/7scenes.yaml): depth is re-projected into the
  colour camera with OpenCV's `registerDepth` (`pipelines.geometry.register_depth`), frames
  carry `K_color`, and ground-truth poses become colour-camera poses
  `T_world_color = T_world_depth @ inv(T_color_depth)`.
  With the lens's radial distortion (`color_k1_k2`), colour images are first resampled to the
  pinhole `K_color` (OpenCV `initUndistortRectifyMap` + `remap`).

The published pose matrices are not exactly orthonormal (rotation blocks deviate from
SO(3) by up to ~1e-4). They are projected onto SO(3) (nearest rotation, SVD) on read, so
every pose is a proper rigid transform and survives quaternion round trips exactly.
"""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import numpy as np

from litevloc.base.geometry import check_rigid, invert, project_to_so3, register_depth
from litevloc.hw.messages import RgbdFrame, StreamError
from litevloc.hw.streams.posed_folder import FrameRecord, PosedFolderSource, read_matrix_4x4

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

    def __init__(
        self, folder: str | Path, frames: slice = slice(None), strict: bool = True,
        K_color: np.ndarray | None = None, T_color_depth: np.ndarray | None = None, depth_dilation: bool = False,
        color_k1_k2: tuple[float, float] = (0.0, 0.0),
    ) -> None:
        root = Path(folder)
        if (K_color is None) != (T_color_depth is None):
            raise StreamError("7-Scenes calibration needs both K_color and T_color_depth (or neither)")
        T_depth_color = None
        if K_color is not None and T_color_depth is not None:
            K_color = np.asarray(K_color, dtype=np.float64)
            if K_color.shape != (3, 3) or not np.all(np.isfinite(K_color)) or K_color[0, 0] <= 0 or K_color[1, 1] <= 0:
                raise StreamError(f"K_color must be a valid 3x3 intrinsics matrix, got {K_color.tolist()}")
            T_depth_color = invert(check_rigid(np.asarray(T_color_depth, dtype=np.float64), "T_color_depth"))
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
                if T_depth_color is not None:
                    T = T @ T_depth_color
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
        K_depth = read_intrinsics(root)
        self.K_depth = K_depth
        self.T_color_depth = None if T_depth_color is None else invert(T_depth_color)
        self.depth_dilation = depth_dilation
        if any(color_k1_k2) and K_color is None:
            raise StreamError("7-Scenes colour distortion needs the colour intrinsics (K_color) too")
        self.color_k1_k2 = (float(color_k1_k2[0]), float(color_k1_k2[1]))
        self._undistort_maps: tuple[np.ndarray, np.ndarray] | None = None
        super().__init__(f"7scenes:{root.name}", records, K_depth if K_color is None else K_color, 1000.0, frames,
                         strict)
        for reason in pose_problems:
            self.stats.skip(reason.split(":")[0])

    def decode(self, rec: FrameRecord) -> RgbdFrame:
        """Decode one frame; with a calibration, depth is registered to the colour camera."""
        frame = super().decode(rec)
        if any(self.color_k1_k2):
            frame = dataclasses.replace(frame, color=self._undistort(frame.color))
        if self.T_color_depth is None or frame.depth is None:
            return frame
        depth = register_depth(frame.depth, self.K_depth, self.K, self.T_color_depth,
                               (frame.width, frame.height), self.depth_dilation)
        return dataclasses.replace(frame, depth=depth)

    def _undistort(self, color: np.ndarray) -> np.ndarray:
        """The colour image resampled to the pinhole camera `K_color` (radial k1, k2 removed)."""
        import cv2

        h, w = color.shape[:2]
        if self._undistort_maps is None or self._undistort_maps[0].shape != (h, w):
            K = np.asarray(self.K, dtype=np.float64)
            dist = np.array([self.color_k1_k2[0], self.color_k1_k2[1], 0.0, 0.0, 0.0])
            m1, m2 = cv2.initUndistortRectifyMap(K, dist, None, K, (w, h), cv2.CV_32FC1)
            self._undistort_maps = (m1, m2)
        m1, m2 = self._undistort_maps
        return np.ascontiguousarray(cv2.remap(color, m1, m2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE))
