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
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from litevloc.cli.common import add_config_args, add_frames_arg, add_json_arg, config_of, source_of
from litevloc.cli.main import UserError
from litevloc.pipelines.localization.vloc import VisualLocalizer
from litevloc.pipelines.topomap.io import load_map
from litevloc.pipelines.topomap.map_save import save_map
from litevloc.pipelines.topomap.merge import MapMergeError
from litevloc.pipelines.topomap.session import OncePerImage, SessionFrame, update_from_session
from litevloc.runtime.tools.outputs import progress, write_json
from litevloc.runtime.tools.posed import posed_frames


def add_update_parser(msub: argparse._SubParsersAction) -> None:
    p = msub.add_parser("update", help="refresh a map from a new session: add keyframes where the place is new or "
                                       "changed, retire keyframes that no longer match (writes a new map)")
    p.add_argument("map", type=Path, help="the map to update (never modified)")
    p.add_argument("src", type=Path, help="dataset folder or .mcap recording of the new session")
    p.add_argument("-o", "--output", type=Path, required=True, help="folder of the new map version")
    p.add_argument("--force", action="store_true", help="replace an existing output folder")
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
    from litevloc.runtime.vloc_models import check_map_models, load_bundle, second_look_for

    if args.output.resolve() == args.map.resolve():
        raise UserError(f"{args.output}: the new version must go to another folder (the map is never modified)")
    if args.output.exists() and not args.force:
        raise UserError(f"{args.output} exists; pass --force to replace it")
    if args.every < 1:
        raise UserError("--every must be >= 1")
    cfg = config_of(args)
    bundle = load_bundle(cfg.models)
    topomap = check_map_models(load_map(args.map), bundle)
    extract, describe = OncePerImage(bundle.extract), OncePerImage(bundle.describe)
    loc = VisualLocalizer(topomap, cfg.localization, extract, describe, bundle.match,
                          second_look=second_look_for(topomap, cfg.models, cfg.localization, bundle))

    def frames() -> Iterator[SessionFrame]:
        for f, T in posed_frames(source_of(args, cfg)):
            yield SessionFrame(f.t_ns, f.index, f.color, f.depth, f.K, f.color_jpeg, T)

    t0 = time.perf_counter()
    with progress(source_of(args, cfg).frame_count(), "map update") as bar:
        try:
            res = update_from_session(topomap, frames, loc, extract, describe, bundle.match, cfg.mapping,
                                      every=args.every, on_frame=lambda: bar.update(1))
        except (MapMergeError, ValueError) as exc:
            raise UserError(f"map update {args.map} {args.src}: {exc}") from exc
    new_map, report = res.new_map, res.report
    if res.posed_session_aligned_by:
        print(f"{args.src}: session frame aligned to the map by {res.posed_session_aligned_by} localized frames")
    parent_sha = hashlib.sha256((args.map / "manifest.json").read_bytes()).hexdigest()
    summary = {
        "map": str(args.map), "src": str(args.src), "frames": res.frames, "compared": res.compared,
        "skipped_not_moved": res.skipped_not_moved,
        "known_place": report.known, "new_place": report.new_place, "changed_place": report.changed_place,
        "unreliable": report.unreliable, "mapped_view_unmatched": report.mapped_view_unmatched,
        "known_by_added": report.known_by_added,
        "known_by_localization": report.known_by_localization,
        "nodes_before": topomap.n_nodes, "nodes_after": new_map.n_nodes, "added": len(report.added),
        "retired": len(report.retired), "retired_ids": report.retired, "replaced": len(report.replaced),
        "replace_outcomes": report.replace_outcomes,
        "added_fraction": len(report.added) / topomap.n_nodes, "seconds": time.perf_counter() - t0,
        "posed_session_aligned_by": res.posed_session_aligned_by,
    }
    if res.localization_errors_m:
        summary["localization_median_m"] = float(np.median(res.localization_errors_m))
    new_map.meta.update({"parent_map": str(args.map), "parent_manifest_sha256": parent_sha,
                         "update": json.dumps({k: summary[k] for k in ("src", "frames", "compared", "added",
                                                                        "retired", "retired_ids")})})
    save_map(new_map, args.output, overwrite=args.force, descriptor_bytes=cfg.mapping.descriptor_bytes)
    print(f"{args.src}: {res.compared}/{res.frames} frames compared with the map ({res.skipped_not_moved} closer "
          f"than the mapping pre-filter to the last one); places known {report.known}, new {report.new_place}, "
          f"changed {report.changed_place}, unreliable {report.unreliable} ({report.mapped_view_unmatched} of them "
          f"views the map saw from elsewhere; known by a keyframe this update "
          f"added: {report.known_by_added}; by the localization, no keyframe covering them: "
          f"{report.known_by_localization})")
    print(f"wrote {args.output}: {topomap.n_nodes} -> {new_map.n_nodes} keyframes (+{len(report.added)} added, "
          f"-{len(report.retired)} retired, {len(report.replaced)} of them replaced by a fresh keyframe) in "
          f"{summary['seconds']:.1f} s; parent {args.map}")
    write_json(args.json, summary)
    return 0
