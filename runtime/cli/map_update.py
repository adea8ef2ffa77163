"""`litevloc map update MAP SRC -o NEW`: refresh a map from a new session.

The session (posed or not) is localized against MAP with the runtime's localizer; frames at
places the map lacks or whose appearance changed become keyframes, keyframes that no longer
match their place are retired (`pipelines.topomap.update`). MAP is never modified; NEW's
manifest records its parent (path and manifest SHA-256) and what changed.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import Generic, TypeVar

import cv2
import numpy as np

from litevloc.base.geometry import backproject_depth, invert, relative_pose_error
from litevloc.hw.messages import RgbdFrame
from litevloc.pipelines.depth_lookup import depth_at
from litevloc.pipelines.localization.vloc import VisualLocalizer
from litevloc.pipelines.topomap.io import load_map, save_map
from litevloc.pipelines.topomap.keyframes import moved
from litevloc.pipelines.topomap.merge import MapMergeError, MergeParams, robust_alignment
from litevloc.pipelines.topomap.types import NodeFeatures
from litevloc.pipelines.topomap.update import MapUpdate, Observation, UpdateParams
from litevloc.runtime.cli.common import (
    add_config_args,
    add_frames_arg,
    add_json_arg,
    config_of,
    progress,
    source_of,
    write_json,
)
from litevloc.runtime.cli.main import UserError
from litevloc.runtime.posed import posed_frames

_Out = TypeVar("_Out")


class _OncePerImage(Generic[_Out]):
    """`fn(image)` computed once per image object: the update extracts a frame's features and
    VPR descriptor for its localization and again for its observation (the same arrays)."""

    def __init__(self, fn: Callable[[np.ndarray], _Out]) -> None:
        self._fn = fn
        self._image: np.ndarray | None = None  # held, so its identity cannot be reused
        self._out: _Out | None = None

    def __call__(self, image: np.ndarray) -> _Out:
        if image is not self._image or self._out is None:
            self._out = self._fn(image)
            self._image = image
        return self._out


def add_update_parser(msub: argparse._SubParsersAction) -> None:
    p = msub.add_parser("update", help="refresh a map from a new session: add keyframes where the place is new or "
                                       "changed, retire keyframes that no longer match (writes a new map)")
    p.add_argument("map", type=Path, help="the map to update (never modified)")
    p.add_argument("src", type=Path, help="dataset folder or .mcap recording of the new session")
    p.add_argument("-o", "--output", type=Path, required=True, help="folder of the new map version")
    p.add_argument("--force", action="store_true", help="replace an existing output folder")
    p.add_argument("--align-every", type=int, default=5, metavar="N",
                   help="posed sessions: localize every N-th frame to align the session to the map (default 5)")
    p.add_argument("--align-frames", type=int, default=40, metavar="N",
                   help="posed sessions: stop aligning after N localized frames (default 40)")
    p.add_argument("--every", type=int, default=1, metavar="N",
                   help="consider every N-th frame of the session (default 1: all); of those, a frame is "
                        "compared with the map only after the camera moved or turned by the mapping "
                        "pre-filter's mapping.keyframes.min_translation_m / min_rotation_deg since the last "
                        "compared frame")
    add_frames_arg(p)
    add_config_args(p)
    add_json_arg(p)
    p.set_defaults(func=update)


def update(args: argparse.Namespace) -> int:
    from litevloc.runtime.vloc_models import check_map_models, load_bundle

    if args.output.resolve() == args.map.resolve():
        raise UserError(f"{args.output}: the new version must go to another folder (the map is never modified)")
    if args.output.exists() and not args.force:
        raise UserError(f"{args.output} exists; pass --force to replace it")
    if min(args.align_every, args.align_frames, args.every) < 1:
        raise UserError("--align-every, --align-frames and --every must be >= 1")
    cfg = config_of(args)
    bundle = load_bundle(cfg.models)
    topomap = check_map_models(load_map(args.map), bundle)
    extract, describe = _OncePerImage(bundle.extract), _OncePerImage(bundle.describe)
    loc = VisualLocalizer(topomap, cfg.localization, extract, describe, bundle.match)
    upd = MapUpdate(topomap, bundle.match, UpdateParams())
    kp = cfg.mapping.keyframes
    t0 = time.perf_counter()
    # A posed session (its own trajectory, in its own frame): localize every --align-every-th
    # frame, align the session's frame to the map robustly (as `map merge` aligns sessions),
    # then pose every frame through that alignment -- new places get poses too, and no frame
    # needs global localization. An unposed session: every frame is localized.
    T_map_session: np.ndarray | None = None
    estimates, at, weights = [], [], []
    for frame, T_gt in posed_frames(source_of(args, cfg)):
        if T_gt is None or frame.index % args.align_every:
            continue
        res = loc.process(frame.t_ns, frame.color, frame.depth, frame.K)
        if res.accepted and res.T_map_camera is not None:
            estimates.append(res.T_map_camera @ invert(T_gt))
            at.append(T_gt)
            weights.append(res.n_inliers)
            if len(estimates) >= args.align_frames:
                break
    aligned = 0
    if estimates:
        try:
            al = robust_alignment(estimates, at, weights, MergeParams(), what="localized session frames")
        except MapMergeError as exc:
            raise UserError(f"map update {args.map} {args.src}: {exc}") from exc
        T_map_session = al.T_A_B
        aligned = int(al.consistent.sum())
        print(f"{args.src}: session frame aligned to the map by {aligned}/{len(estimates)} localized frames")
    src = source_of(args, cfg)
    n_frames, n_loc, n_still, errors = 0, 0, 0, []
    last_T: np.ndarray | None = None  # pose of the last frame compared with the map
    with progress(src.frame_count(), "map update") as bar:
        for frame, T_gt in posed_frames(src):
            bar.update(1)
            n_frames += 1
            if frame.depth is None or frame.index % args.every:
                continue
            inliers = 0
            localize: Callable[[], int] | None = None
            if T_map_session is not None:
                if T_gt is None:
                    continue
                T = T_map_session @ T_gt
                if last_T is not None and not moved(last_T, T, kp):
                    n_still += 1
                    continue

                def localize(f: RgbdFrame = frame, T_prior: np.ndarray = T) -> int:
                    res = loc.localize_local(f.t_ns, f.color, f.depth, f.K, T_prior)
                    return res.n_inliers if res.accepted else 0
            else:  # the localizer tracks every frame; only frames that moved are compared
                res = loc.process(frame.t_ns, frame.color, frame.depth, frame.K)
                if not res.accepted or res.T_map_camera is None:
                    continue
                T, inliers = res.T_map_camera, res.n_inliers
                if T_gt is not None:
                    errors.append(relative_pose_error(T, T_gt))
                if last_T is not None and not moved(last_T, T, kp):
                    n_still += 1
                    continue
            last_T = T
            n_loc += 1
            feats = extract(frame.color)
            pts_cam, _ = backproject_depth(frame.depth, frame.K, stride=kp.pixel_stride)
            pts_cam = pts_cam[pts_cam[:, 2] <= kp.max_depth_m]
            jpeg = frame.color_jpeg
            if jpeg is None:
                ok, enc = cv2.imencode(".jpg", frame.color[:, :, ::-1], [cv2.IMWRITE_JPEG_QUALITY,
                                                                        cfg.mapping.jpeg_quality])
                if not ok:
                    raise UserError(f"JPEG encoding of frame {frame.index} failed")
                jpeg = enc.tobytes()
            h, w = frame.color.shape[:2]
            kp_depth = depth_at(frame.depth, feats.keypoints, cfg.mapping.depth)
            upd.observe(Observation(
                t_ns=frame.t_ns, index=frame.index, T_map_camera=T, K=np.asarray(frame.K, np.float64),
                image_size=(w, h),
                features=NodeFeatures(np.asarray(feats.keypoints, np.float32), np.asarray(feats.descriptors),
                                      np.asarray(feats.scores, np.float32), (w, h), kp_depth),
                keypoint_depth=kp_depth,
                vpr=np.asarray(describe(frame.color), np.float32), jpeg=jpeg,
                points_map=(pts_cam[:: 4] @ T[:3, :3].T + T[:3, 3]).astype(np.float32),
                localization_inliers=inliers,
            ), localize)
    if n_loc == 0:
        raise UserError(f"{args.src}: no frame localized against {args.map}; nothing to update from")

    new_map, report = upd.finish(cfg.mapping.covisibility, cfg.mapping.connectivity, cfg.mapping.occupancy)
    parent_sha = hashlib.sha256((args.map / "manifest.json").read_bytes()).hexdigest()
    summary = {
        "map": str(args.map), "src": str(args.src), "frames": n_frames, "compared": n_loc,
        "skipped_not_moved": n_still,
        "known_place": report.known, "new_place": report.new_place, "changed_place": report.changed_place,
        "unreliable": report.unreliable, "known_by_added": report.known_by_added,
        "known_by_localization": report.known_by_localization,
        "nodes_before": topomap.n_nodes, "nodes_after": new_map.n_nodes, "added": len(report.added),
        "retired": len(report.retired), "retired_ids": report.retired,
        "added_fraction": len(report.added) / topomap.n_nodes, "seconds": time.perf_counter() - t0,
        "posed_session_aligned_by": aligned,
    }
    if errors:
        e = np.asarray(errors)
        summary["localization_median_m"] = float(np.median(e[:, 0]))
    new_map.meta.update({"parent_map": str(args.map), "parent_manifest_sha256": parent_sha,
                         "update": json.dumps({k: summary[k] for k in ("src", "frames", "compared", "added",
                                                                        "retired", "retired_ids")})})
    save_map(new_map, args.output, overwrite=args.force, descriptor_bytes=cfg.mapping.descriptor_bytes)
    print(f"{args.src}: {n_loc}/{n_frames} frames compared with the map ({n_still} closer than the mapping "
          f"pre-filter to the last one); places known {report.known}, new {report.new_place}, changed "
          f"{report.changed_place}, unreliable {report.unreliable} (known by a keyframe this update added: "
          f"{report.known_by_added}; by the localization, no keyframe covering them: "
          f"{report.known_by_localization})")
    print(f"wrote {args.output}: {topomap.n_nodes} -> {new_map.n_nodes} keyframes (+{len(report.added)} added, "
          f"-{len(report.retired)} retired) in {summary['seconds']:.1f} s; parent {args.map}")
    write_json(args.json, summary)
    return 0
