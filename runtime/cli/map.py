"""`litevloc map build|info|plot`: build a map-lite topo-metric map and inspect it."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from litevloc.pipelines.topomap.build import MapBuilder
from litevloc.pipelines.topomap.io import load_map, save_map, storage_summary
from litevloc.pipelines.topomap.plot import plot_map
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


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("map", help="build, inspect and plot maps")
    msub = p.add_subparsers(dest="map_command", metavar="ACTION")
    msub.required = True
    b = msub.add_parser("build", help="build a map from a posed recording or dataset")
    b.add_argument("src", type=Path, help="dataset folder or .mcap recording with ground-truth poses")
    b.add_argument("-o", "--output", type=Path, required=True, help="map folder to write")
    b.add_argument("--force", action="store_true", help="replace an existing map folder")
    add_frames_arg(b)
    add_config_args(b)
    add_json_arg(b)
    b.set_defaults(func=build)
    i = msub.add_parser("info", help="nodes, edges and storage of a map")
    i.add_argument("map", type=Path)
    add_json_arg(i)
    i.set_defaults(func=info)
    pl = msub.add_parser("plot", help="top-down PNG of nodes and both edge sets over the occupancy grid")
    pl.add_argument("map", type=Path)
    pl.add_argument("-o", "--output", type=Path, required=True, help="PNG to write")
    pl.set_defaults(func=plot)
    from litevloc.runtime.cli.map_diff import add_diff_parser

    add_diff_parser(msub)
    from litevloc.runtime.cli.map_merge import add_merge_parser

    add_merge_parser(msub)
    from litevloc.runtime.cli.map_update import add_update_parser

    add_update_parser(msub)


def build(args: argparse.Namespace) -> int:
    from litevloc.runtime.vloc_models import load_bundle

    cfg = config_of(args)
    if args.output.exists() and not args.force:
        raise UserError(f"{args.output} exists; pass --force to replace it")
    bundle = load_bundle(cfg.models, matcher=cfg.mapping.covisibility_matcher)
    src = source_of(args, cfg)
    builder = MapBuilder(cfg.mapping, bundle.extract, bundle.describe, bundle.match, bundle.extractor.name,
                         bundle.vpr.name)
    t0 = time.perf_counter()
    missing_pose = 0
    with progress(src.frame_count(), "map build: frames") as bar:
        for frame, T in posed_frames(src):
            bar.update(1)
            if T is None:
                missing_pose += 1
                continue
            builder.add(frame.t_ns, frame.color, frame.depth, frame.K, T, frame.index, frame.color_jpeg)
    if builder.report.frames == 0:
        raise UserError(f"{args.src}: no frame had a ground-truth pose; a map needs posed images")
    t1 = time.perf_counter()
    sel = builder.select()
    with progress(builder.n_covisibility_pairs(sel), "map build: covisibility", unit="pair") as bar:
        topomap = builder.finish(on_pair=lambda: bar.update(1), selected=sel)
    t2 = time.perf_counter()
    topomap.meta.update({"source": str(args.src), "frames": args.frames or ":", "config": str(args.config)})
    save_map(topomap, args.output, overwrite=args.force)
    storage = storage_summary(args.output)
    r = builder.report
    summary = {
        "map": str(args.output), "frames": r.frames, "frames_without_pose": missing_pose,
        "candidates": r.candidates, "nodes": topomap.n_nodes, "coverage": r.coverage,
        "covisibility_edges": len(topomap.covis_edges), "connectivity_edges": len(topomap.conn_edges),
        "covisibility_pairs_checked": r.covisibility_pairs_checked,
        "seconds_frames": t1 - t0, "seconds_graph": t2 - t1,
        "seconds_per_keyframe": (t2 - t0) / max(topomap.n_nodes, 1), "skipped": r.skipped, **storage,
    }
    print(f"built {args.output}: {topomap.n_nodes} keyframes from {r.frames} frames ({r.candidates} candidates), "
          f"coverage {100 * r.coverage:.1f} %, {len(topomap.covis_edges)} covisibility + "
          f"{len(topomap.conn_edges)} connectivity edges in {t2 - t0:.1f} s "
          f"({summary['seconds_per_keyframe']:.2f} s/keyframe)")
    _print_storage(storage)
    write_json(args.json, summary)
    return 0


def _print_storage(s: dict[str, int]) -> None:
    print(f"storage: graph {s['graph_bytes'] / 1e3:.1f} KB + descriptors {s['descriptor_bytes'] / 1e3:.1f} KB, "
          f"features {s['feature_bytes'] / 1e6:.2f} MB, images {s['image_bytes'] / 1e6:.2f} MB")


def info(args: argparse.Namespace) -> int:
    m = load_map(args.map)
    s = storage_summary(args.map)
    data = {
        "nodes": m.n_nodes, "covisibility_edges": len(m.covis_edges), "connectivity_edges": len(m.conn_edges),
        "extractor": m.extractor, "vpr_model": m.vpr_model, "vpr_dim": int(m.vpr.shape[1]),
        "keypoints_per_node": float(sum(len(f.keypoints) for f in m.features) / m.n_nodes),
        "connectivity_metres_total": float(m.conn_metres.sum()), "grid_cells": list(m.grid.cells.shape),
        "grid_resolution_m": m.grid.resolution, **s,
    }
    print(f"{args.map}: {m.n_nodes} nodes, {len(m.covis_edges)} covisibility edges, "
          f"{len(m.conn_edges)} connectivity edges ({data['connectivity_metres_total']:.1f} m); "
          f"features {m.extractor} ({data['keypoints_per_node']:.0f}/node), VPR {m.vpr_model} ({data['vpr_dim']}-d)")
    _print_storage(s)
    write_json(args.json, data)
    return 0


def plot(args: argparse.Namespace) -> int:
    m = load_map(args.map)
    out = plot_map(m, args.output, title=f"{args.map.name}: {m.n_nodes} keyframes")
    print(f"wrote {out}")
    return 0
