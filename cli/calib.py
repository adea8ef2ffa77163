"""`litevloc calib SRC --frames 0:500:2 -o CALIB.yaml`: colour-camera calibration of an
RGB-D dataset whose depth is not registered to colour (7-Scenes), from posed frames.

Reads the raw frames (depth in the depth camera, depth-camera ground-truth poses, the
published intrinsics as `K_depth`), runs `pipelines.calibration.calibrate_color_depth`
and writes an `rgbd_calibration:` YAML block to paste into a config preset.
Use mapping-pass frames only (7-Scenes: 0-499), so queries stay unseen.
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import numpy as np
import yaml

from litevloc.base.params.calibration import ColorDepthCalibration
from litevloc.cli.common import add_config_args, add_frames_arg, add_json_arg, config_of, frames_of
from litevloc.cli.main import UserError
from litevloc.pipelines.calibration import calibrate_color_depth
from litevloc.runtime.sources import open_source
from litevloc.runtime.tools.outputs import progress, write_json
from litevloc.runtime.tools.posed import posed_frames


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("calib", help="estimate colour intrinsics + depth->colour extrinsic of an RGB-D dataset")
    p.add_argument("src", type=Path, help="dataset folder with unregistered depth and ground-truth poses")
    p.add_argument("-o", "--output", type=Path, required=True, help="YAML file with an rgbd_calibration block")
    add_frames_arg(p)
    add_config_args(p)
    add_json_arg(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    src = open_source(args.src, frames_of(args), strict=True)
    K_depth = getattr(src, "K", None)
    colors, depths, poses = [], [], []
    with progress(src.frame_count(), "calib: frames") as bar:
        for frame, T in posed_frames(src):
            bar.update(1)
            if T is None or frame.depth is None:
                continue
            colors.append(frame.color)
            depths.append(frame.depth.astype(np.float16))  # halves memory; mm-level at kitchen range
            poses.append(T)
            K_depth = frame.K
    if len(colors) < 2 or K_depth is None:
        raise UserError(f"{args.src}: need >= 2 frames with depth and ground truth, got {len(colors)}")
    params = config_of(args).calibration
    K = np.asarray(K_depth)
    init = ColorDepthCalibration(float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]),
                                 params.translation_prior)
    try:
        res = calibrate_color_depth(colors, depths, np.stack(poses), K, init, params)
    except ValueError as exc:
        raise UserError(f"calibration failed: {exc}") from exc
    cal = res.calibration
    block = {k: (list(v) if isinstance(v, tuple) else v) for k, v in dataclasses.asdict(cal).items()}
    block = {k: ([round(x, 6) for x in v] if isinstance(v, list) else round(v, 4) if isinstance(v, float) else v)
             for k, v in block.items()}
    args.output.parent.mkdir(parents=True, exist_ok=True)
    header = (f"# litevloc calib {args.src} --frames {args.frames or ':'}: {res.n_pairs} frame pairs, "
              f"{res.n_residuals} correspondences; median reprojection {res.median_before_px:.2f} px "
              f"(initial guess) -> {res.median_after_px:.2f} px\n")
    args.output.write_text(header + yaml.safe_dump({"rgbd_calibration": block}, sort_keys=False))
    print(f"colour K: fx {cal.color_fx:.1f} fy {cal.color_fy:.1f} cx {cal.color_cx:.1f} cy {cal.color_cy:.1f}; "
          f"T_color_depth t {np.round(cal.translation_color_depth, 4).tolist()} "
          f"q_xyzw {np.round(cal.quat_xyzw_color_depth, 5).tolist()}; k1 {cal.color_k1:.4f} k2 {cal.color_k2:.4f}")
    print(f"median reprojection error {res.median_before_px:.2f} px -> {res.median_after_px:.2f} px "
          f"over {res.n_residuals} correspondences of {res.n_pairs} pairs -> {args.output}")
    write_json(args.json, {"calibration": dataclasses.asdict(cal), "n_pairs": res.n_pairs,
                           "n_residuals": res.n_residuals, "median_before_px": res.median_before_px,
                           "median_after_px": res.median_after_px, "rms_before_px": res.rms_before_px,
                           "rms_after_px": res.rms_after_px, "std": res.std, "output": str(args.output)})
    return 0
