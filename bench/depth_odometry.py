"""Depth odometry benchmark: OpenCV `cv2.Odometry` (via pipelines.depth_odometry) on the
7-Scenes query pass. Per method and frame step: median frame-to-frame translation and
rotation error vs ground truth (with the median true motion as the "assume no motion"
baseline), failures, time per frame, and the chained trajectory's ATE and RPE per metre.
Prints a table; writes out/bench/depth_odometry.json.

    .venv/bin/python bench/depth_odometry.py [SRC] [--frames 500:1000]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from litevloc.base.frames import parse_frames
from litevloc.base.geometry import invert, rotation_angle
from litevloc.base.params.depth import DepthOdometryParams
from litevloc.hw.messages import RgbdFrame
from litevloc.hw.streams.sevenscenes import SevenScenesSource
from litevloc.pipelines.depth_odometry import DepthOdometry
from litevloc.pipelines.evaluation.trajectory import ate, rpe_per_metre

ROOT = Path(__file__).resolve().parents[1]


def run() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument(
        "src", nargs="?", default=str(ROOT.parent / "shared" / "data" / "7scenes-redkitchen")
    )
    ap.add_argument("--frames", default="500:1000")
    a = ap.parse_args()
    cv2.setNumThreads(2)
    sl = parse_frames(a.frames)
    rows = []
    for method in ("depth", "rgb", "rgbd"):
        for step in (1, 3):
            src = SevenScenesSource(a.src, slice(sl.start, sl.stop, step))
            _, gt = src.ground_truth()
            do = DepthOdometry(src.K, DepthOdometryParams(method=method))
            est, et, er, mt, mr, ms = [], [], [], [], [], []
            for i, m in enumerate(x for x in src if isinstance(x, RgbdFrame)):
                t0 = time.perf_counter()
                r = do.step(m.color, m.depth)
                ms.append((time.perf_counter() - t0) * 1e3)
                est.append(r.T_odom_camera)
                if i > 0 and r.ok:
                    G = invert(gt[i - 1]) @ gt[i]
                    D = invert(G) @ r.T_prev_curr
                    et.append(np.linalg.norm(r.T_prev_curr[:3, 3] - G[:3, 3]))
                    er.append(np.degrees(rotation_angle(D[:3, :3])))
                    mt.append(np.linalg.norm(G[:3, 3]))
                    mr.append(np.degrees(rotation_angle(G[:3, :3])))
            E = np.stack(est)
            G0 = invert(gt[0]) @ gt
            rows.append(
                {
                    "method": method,
                    "step": step,
                    "pairs": do.steps,
                    "failures": do.failures,
                    "trans_err_mm_median": 1e3 * float(np.median(et)),
                    "motion_mm_median": 1e3 * float(np.median(mt)),
                    "rot_err_deg_median": float(np.median(er)),
                    "motion_deg_median": float(np.median(mr)),
                    "ms_per_frame_median": float(np.median(ms[1:])),
                    "ate_m": ate(E, G0).rmse,
                    "rpe_per_m_median": rpe_per_metre(E, G0, 1.0).median,
                }
            )
            r_ = rows[-1]
            print(
                f"{method:<6}step {step}  err {r_['trans_err_mm_median']:5.1f} mm (motion "
                f"{r_['motion_mm_median']:5.1f})  {r_['rot_err_deg_median']:.3f} deg (motion "
                f"{r_['motion_deg_median']:.3f})  fail {r_['failures']:3d}/{r_['pairs']:3d}  "
                f"{r_['ms_per_frame_median']:5.1f} ms  ATE {r_['ate_m']:.3f} m  "
                f"RPE {r_['rpe_per_m_median']:.3f} m/m"
            )
    out = ROOT / "out" / "bench" / "depth_odometry.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(
        json.dumps({"frames": a.frames, "opencv": cv2.__version__, "rows": rows}, indent=2) + "\n"
    )
    return 0


if __name__ == "__main__":
    sys.exit(run())
