"""Reader for TUM RGB-D benchmark folders.

Layout: `rgb.txt` and `depth.txt` (`timestamp filename` lines, `#` comments),
`groundtruth.txt` (`timestamp tx ty tz qx qy qz qw`, T_world_camera), PNG images.
Depth PNGs are uint16 with **5000 units per metre** (0 invalid). Colour and depth are
associated by nearest timestamp within `max_dt_s` (0.02 s, as the TUM tools do); ground
truth is interpolated at the colour timestamp (no extrapolation: frames outside the
ground-truth span get no pose).

Intrinsics: from an optional `intrinsics.txt` (3x3 K) in the folder, else the
published ROS-default values for the `freiburg1/2/3` camera named in the folder name,
else an error (never a silent guess).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from litevloc.base.geometry import (
    GeometryError,
    interpolate_pose_at,
    make_T,
    quat_xyzw_to_matrix,
)
from litevloc.hw.messages import StreamError
from litevloc.hw.streams.posed_folder import FrameRecord, PosedFolderSource

# Published TUM intrinsics (fx, fy, cx, cy) per Kinect.
TUM_INTRINSICS = {
    "freiburg1": (517.3, 516.5, 318.6, 255.3),
    "freiburg2": (520.9, 521.0, 325.1, 249.7),
    "freiburg3": (535.4, 539.2, 320.1, 247.6),
}


def is_tum_folder(path: Path) -> bool:
    return path.is_dir() and (path / "rgb.txt").is_file()


def _read_list(path: Path, ncols: int) -> list[list[str]]:
    if not path.is_file():
        raise StreamError(f"TUM list file missing: {path}")
    rows = []
    for lineno, line in enumerate(path.read_text().splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        parts = line.replace(",", " ").split()
        if len(parts) < ncols:
            raise StreamError(f"{path}:{lineno}: expected {ncols} columns, got {len(parts)}")
        rows.append(parts)
    return rows


def _ts_ns(s: str, where: str) -> int:
    try:
        v = float(s)
    except ValueError as exc:
        raise StreamError(f"{where}: bad timestamp {s!r}") from exc
    if not np.isfinite(v):
        raise StreamError(f"{where}: non-finite timestamp {s!r}")
    return round(v * 1e9)


def _intrinsics(root: Path) -> NDArray[np.float64]:
    f = root / "intrinsics.txt"
    if f.is_file():
        K = np.loadtxt(str(f))
        if K.shape != (3, 3):
            raise StreamError(f"{f}: must hold a 3x3 matrix")
        return K
    for key, (fx, fy, cx, cy) in TUM_INTRINSICS.items():
        if key in root.name:
            return np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])
    raise StreamError(
        f"{root}: no intrinsics.txt and the folder name names no freiburg1/2/3 camera; "
        "add intrinsics.txt with the 3x3 K"
    )


class TumRgbdSource(PosedFolderSource):
    """A TUM RGB-D sequence folder as a stream of RgbdFrame + GroundTruthPose."""

    def __init__(
        self, folder: str | Path, frames: slice = slice(None), strict: bool = True, max_dt_s: float = 0.02
    ) -> None:
        root = Path(folder)
        if not root.is_dir():
            raise StreamError(f"TUM folder not found: {root}")
        rgb = _read_list(root / "rgb.txt", 2)
        depth_rows = _read_list(root / "depth.txt", 2) if (root / "depth.txt").is_file() else []
        d_t = np.array([_ts_ns(r[0], str(root / "depth.txt")) for r in depth_rows], dtype=np.int64)
        gt_t = np.zeros(0, dtype=np.int64)
        gt_T = np.zeros((0, 4, 4))
        gt_file = root / "groundtruth.txt"
        if gt_file.is_file():
            rows = _read_list(gt_file, 8)
            gt_t = np.array([_ts_ns(r[0], str(gt_file)) for r in rows], dtype=np.int64)
            try:
                gt_T = np.stack(
                    [make_T(quat_xyzw_to_matrix(np.array(r[4:8], float)), np.array(r[1:4], float)) for r in rows]
                )
            except (ValueError, GeometryError) as exc:
                raise StreamError(f"{gt_file}: malformed pose line: {exc}") from exc
            order = np.argsort(gt_t, kind="stable")
            gt_t, gt_T = gt_t[order], gt_T[order]
        records = []
        max_dt = int(max_dt_s * 1e9)
        for i, row in enumerate(rgb):
            t = _ts_ns(row[0], str(root / "rgb.txt"))
            depth_path = None
            if len(d_t):
                j = int(np.argmin(np.abs(d_t - t)))
                if abs(int(d_t[j]) - t) <= max_dt:
                    depth_path = root / depth_rows[j][1]
            T = None
            if len(gt_t) >= 2 and gt_t[0] <= t <= gt_t[-1]:
                T = interpolate_pose_at(t, gt_t, gt_T)
            records.append(FrameRecord(i, t, root / row[1], depth_path, T))
        super().__init__(f"tum:{root.name}", records, _intrinsics(root), 5000.0, frames, strict)
