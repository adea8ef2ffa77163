"""`litevloc calib SRC --frames 0:500:3 -o CALIB.yaml`: colour-camera calibration of an
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
from litevloc.pipelines.calibration import CalibrationParams, calibrate_color_depth
from litevloc.runtime.cli.common import add_frames_arg, add_json_arg, frames_of, progress, write_json
from litevloc.runtime.cli.main import UserError
from litevloc.runtime.posed import posed_frames
from litevloc.runtime.sources import open_source


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("calib", help="estimate colour intrinsics + depth->colour extrinsic of an RGB-D dataset")
    p.add_argument("src", type=Path, help="dataset folder with unregistered depth and ground-truth poses")
    p.add_argument("-o", "--output", type=Path, required=True, help="YAML file with an rgbd_calibration block")
    p.add_argument("--translation-prior", type=float, nargs=3, default=(-0.025, 0.0, 0.0), metavar=("X", "Y", "Z"),
                   help="T_color_depth translation in metres, kept fixed unless --estimate-translation "
                        "(default: Kinect v1 nominal, colour camera 2.5 cm along +x of the depth camera)")
    p.add_argument("--estimate-translation", action="store_true",
                   help="also estimate the translation (weakly observable; see pipelines/calibration.py)")
    p.add_argument("--estimate-distortion", action="store_true",
                   help="also estimate the colour lens's radial distortion k1, k2")
    p.add_argument("--pair-gaps", type=int, nargs="+", default=None, metavar="N",
                   help="pair each frame with the one N positions later in the selected frames (default: "
                        f"{' '.join(map(str, CalibrationParams.pair_gaps))}: wide viewpoint changes, like a "
                        "live frame's to its keyframe)")
    add_frames_arg(p)
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
    try:
        gaps = CalibrationParams.pair_gaps if args.pair_gaps is None else tuple(args.pair_gaps)
        params = CalibrationParams(pair_gaps=gaps, min_parallax_m=0.02,
                                   estimate_translation=args.estimate_translation,
                                   estimate_distortion=args.estimate_distortion)
    except ValueError as exc:
        raise UserError(str(exc)) from exc
    K = np.asarray(K_depth)
    tx, ty, tz = (float(v) for v in args.translation_prior)  # argparse nargs=3: exactly three
    init = ColorDepthCalibration(float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]), (tx, ty, tz))
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
