"""`litevloc map merge A B [...] -o MERGED`: join sessions mapped in different world frames.

Every later map is linked, robustly aligned and joined into the frame of the first map
(`pipelines.topomap.merge`). The inputs are never modified; the merged map's manifest
records its sessions and each alignment.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from litevloc.base.geometry import rotation_angle
from litevloc.cli.common import add_config_args, add_json_arg, config_of
from litevloc.cli.main import UserError
from litevloc.pipelines.topomap.io import load_map, storage_summary
from litevloc.pipelines.topomap.map_save import save_map
from litevloc.pipelines.topomap.merge import MapMergeError, merge_sessions
from litevloc.runtime.tools.outputs import progress, write_json


def add_merge_parser(msub: argparse._SubParsersAction) -> None:
    p = msub.add_parser("merge", help="join maps of sessions recorded in different frames into the first one's frame")
    p.add_argument("maps", type=Path, nargs="+", help="map folders; the first one's frame is kept")
    p.add_argument("-o", "--output", type=Path, required=True, help="merged map folder to write")
    p.add_argument("--force", action="store_true", help="replace an existing output folder")
    add_config_args(p)
    add_json_arg(p)
    p.set_defaults(func=merge)


def merge(args: argparse.Namespace) -> int:
    from litevloc.runtime.vloc_models import check_map_models, load_bundle

    if len(args.maps) < 2:
        raise UserError("map merge needs at least two maps")
    if args.output.exists() and not args.force:
        raise UserError(f"{args.output} exists; pass --force to replace it")
    if args.output.resolve() in {m.resolve() for m in args.maps}:
        raise UserError(f"{args.output}: the output must not be one of the inputs (inputs are never modified)")
    cfg = config_of(args)
    params = cfg.mapping.merge
    bundle = load_bundle(cfg.models)
    merged = check_map_models(load_map(args.maps[0]), bundle)
    merged.meta.setdefault("source", str(args.maps[0]))
    t0 = time.perf_counter()
    sessions = []
    for path in args.maps[1:]:
        other = check_map_models(load_map(path), bundle)
        other.meta["source"] = str(path)
        t1 = time.perf_counter()
        try:
            with progress(other.n_nodes, f"map merge: {path.name}", unit="keyframe") as bar:
                merged, report, alignment, _ = merge_sessions(merged, other, bundle.match, params,
                                                              on_node=lambda: bar.update(1))
        except MapMergeError as exc:
            raise UserError(f"map merge {args.maps[0]} + {path}: {exc}") from exc
        T = alignment.T_A_B
        rec = {"map": str(path), "seconds": time.perf_counter() - t1, **report.__dict__,
               "T_first_this": T.tolist(),
               "alignment_translation_m": float(np.linalg.norm(T[:3, 3])),
               "alignment_rotation_deg": float(np.degrees(rotation_angle(T[:3, :3]))),
               "link_residual_median_m": float(np.median(alignment.residual_m[alignment.consistent]))}
        rec.pop("T_A_B", None)
        sessions.append(rec)
        print(f"{path}: {report.links_consistent}/{report.links_verified} cross-session links agree "
              f"({report.links_tried} pairs tried); frame offset {rec['alignment_translation_m']:.2f} m, "
              f"{rec['alignment_rotation_deg']:.1f} deg; {report.nodes_b} keyframes, {report.nodes_dropped} "
              f"duplicates dropped; +{report.cross_covisibility_edges} covisibility, "
              f"+{report.cross_connectivity_edges} connectivity edges across sessions")
    merged.meta["sessions"] = json.dumps([str(m) for m in args.maps])
    save_map(merged, args.output, overwrite=args.force, descriptor_bytes=cfg.mapping.descriptor_bytes)
    s = storage_summary(args.output)
    print(f"wrote {args.output}: {merged.n_nodes} keyframes, {len(merged.covis_edges)} covisibility + "
          f"{len(merged.conn_edges)} connectivity edges in {time.perf_counter() - t0:.1f} s")
    write_json(args.json, {"output": str(args.output), "nodes": merged.n_nodes, "sessions": sessions,
                           "seconds": time.perf_counter() - t0, **s})
    return 0
