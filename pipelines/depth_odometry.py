"""Frame-to-frame RGB-D odometry (fallback for sources without proprioceptive odometry).

A thin wrapper over OpenCV 5's `cv2.Odometry` (3d/ptcloud module): dense ICP on depth
(`method="depth"`, the default), photometric (`"rgb"`) or both (`"rgbd"`). We do not
hand-write ICP. Measured with `bench/depth_odometry.py` on the 7-Scenes query pass
(frames 500-999, 640x480, OpenCV 5.0.0, 2 threads, shared 2-core machine); errors of
each frame-to-frame estimate vs ground truth, medians:

| method | step | trans. err (motion) | rot. err (motion) | fails | ms | chained ATE | RPE |
|---|---|---|---|---|---|---|---|
| depth | 1 (30 Hz) | 3.7 mm (7.0) | 0.15 deg (0.49) | 18/499 | 40 | 0.149 m | 0.25 m/m |
| depth | 3 (10 Hz) | 4.0 mm (18.3) | 0.15 deg (1.21) | 12/166 | 39 | 0.173 m | 0.28 m/m |
| rgb | 1 | 4.2 mm | 0.13 deg | 18/499 | 31 | 0.140 m | 0.21 m/m |
| rgbd | 1 | 3.4 mm | 0.12 deg | 18/499 | 69 | 0.131 m | 0.22 m/m |

Per-step error barely depends on the step (it is not proportional to motion), so ICP at
~10 Hz gives the best error per metre of motion per CPU-second; "rgbd" is slightly more
accurate at 30 Hz for 1.7x the time. Chained over 3.15 m the drift is large (ATE
0.13-0.17 m): this is a fallback for short gaps between VLoc fixes, not a substitute
for proprioceptive odometry. 7-Scenes ground truth is itself from KinectFusion and its
colour/depth are unregistered, so millimetre-level "errors" are partly the reference's.
OpenCV reports failure on 2-7 % of pairs — the same pairs for all three methods, and not
because of the max translation/rotation limits (raising them changes nothing); a failed
step holds the pose and is counted in `failures`. Defaults are OpenCV's.

Conventions: depth HxW float32 metres, NaN (or <= 0) invalid; colour HxWx3 uint8 RGB;
`K` 3x3. Output poses are of the camera (optical) frame: `T_prev_curr` per step and
the chained `T_odom_camera` with `T_odom_camera = I` at the first frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from litevloc.base.geometry import invert
from litevloc.base.params.depth import DepthOdometryParams

F64 = NDArray[np.float64]

_TYPES = {
    "depth": cv2.OdometryType_DEPTH,
    "rgb": cv2.OdometryType_RGB,
    "rgbd": cv2.OdometryType_RGB_DEPTH,
}


@dataclass(frozen=True)
class OdometryStep:
    """Result of one `DepthOdometry.step`: ok, T_prev_curr (4x4; identity when not ok),
    and the chained T_odom_camera after this frame."""

    ok: bool
    T_prev_curr: F64
    T_odom_camera: F64


class DepthOdometry:
    """Chain OpenCV RGB-D odometry over consecutive frames.

    A failed step (OpenCV reports failure, or the estimate exceeds the per-step motion
    limits) keeps the pose unchanged and is counted in `failures`; the next step is
    computed against the newest frame.
    """

    def __init__(self, K: NDArray[np.floating], params: DepthOdometryParams | None = None) -> None:
        Kf = np.asarray(K, dtype=np.float64)
        if Kf.shape != (3, 3) or not np.isfinite(Kf).all() or Kf[0, 0] <= 0 or Kf[1, 1] <= 0:
            raise ValueError(f"K must be a valid 3x3 intrinsics matrix, got {Kf.tolist()}")
        self.params = params or DepthOdometryParams()
        p = self.params
        s = cv2.OdometrySettings()
        s.setCameraMatrix(Kf.astype(np.float32))  # OpenCV 5 asserts CV_32F here
        s.setMinDepth(p.min_depth)
        s.setMaxDepth(p.max_depth)
        s.setMaxDepthDiff(p.max_depth_diff)
        s.setMaxTranslation(p.max_translation)
        s.setMaxRotation(p.max_rotation_deg)
        self._odo = cv2.Odometry(_TYPES[p.method], s, cv2.OdometryAlgoType_COMMON)
        self._prev: cv2.OdometryFrame | None = None
        self._shape: tuple[int, int] | None = None
        self.T_odom_camera: F64 = np.eye(4)
        self.steps = 0
        self.failures = 0

    def _frame(
        self, color: NDArray[np.uint8] | None, depth: NDArray[np.floating]
    ) -> cv2.OdometryFrame:
        d = np.asarray(depth, dtype=np.float32)
        if d.ndim != 2:
            raise ValueError(f"depth must be HxW, got shape {d.shape}")
        if self._shape is not None and d.shape != self._shape:
            raise ValueError(f"depth size changed from {self._shape} to {d.shape}")
        d = np.where(np.isfinite(d) & (d > 0), d, np.float32(np.nan))
        if self.params.method == "depth":
            f = cv2.OdometryFrame(depth=d)
        else:
            if color is None:
                raise ValueError(f"method {self.params.method!r} needs a colour image")
            c = np.asarray(color)
            if c.shape[:2] != d.shape or c.ndim != 3 or c.dtype != np.uint8:
                raise ValueError(
                    f"colour must be HxWx3 uint8 matching depth {d.shape}, got {c.dtype} {c.shape}"
                )
            f = cv2.OdometryFrame(depth=d, image=cv2.cvtColor(c, cv2.COLOR_RGB2GRAY))
        self._odo.prepareFrame(f)
        self._shape = d.shape
        return f

    def step(self, color: NDArray[np.uint8] | None, depth: NDArray[np.floating]) -> OdometryStep:
        """Add one frame; returns the motion since the previous frame (identity on the first)."""
        cur = self._frame(color, depth)
        prev, self._prev = self._prev, cur
        if prev is None:
            return OdometryStep(True, np.eye(4), self.T_odom_camera.copy())
        self.steps += 1
        ok, Rt = self._odo.compute(prev, cur)  # Rt maps points of prev into cur: T_curr_prev
        Rt = np.asarray(Rt, dtype=np.float64)
        if not ok or Rt.shape != (4, 4) or not np.isfinite(Rt).all():
            self.failures += 1
            return OdometryStep(False, np.eye(4), self.T_odom_camera.copy())
        T_prev_curr = invert(np.asarray(Rt, dtype=np.float64))
        self.T_odom_camera = self.T_odom_camera @ T_prev_curr
        return OdometryStep(True, T_prev_curr, self.T_odom_camera.copy())
