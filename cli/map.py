"""`litevloc map build|info|plot`: build a map-lite topo-metric map and inspect it."""

from __future__ import annotations

import argparse
from pathlib import Path

from litevloc.cli.common import add_config_args, add_frames_arg, add_json_arg, config_of
from litevloc.cli.map_build import add_pose_args, build
from litevloc.pipelines.topomap.io import load_map, storage_summary
from litevloc.pipelines.topomap.plot import plot_map
from litevloc.runtime.tools.map_building import print_openings, print_storage
from litevloc.runtime.tools.outputs import write_json


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("map", help="build, inspect and plot maps")
    msub = p.add_subparsers(dest="map_command", metavar="ACTION")
    msub.required = True
    b = msub.add_parser("build", help="build a map from a recording, dataset or simulated pass (posed by "
                                      "ground truth, odometry, its own SLAM or a trajectory file)")
    b.add_argument("src", type=Path, help="dataset folder, .mcap recording or sim:WORLD?pass=map")
    b.add_argument("-o", "--output", type=Path, required=True, help="map folder to write")
    b.add_argument("--force", action="store_true", help="replace an existing map folder")
    add_frames_arg(b)
    add_pose_args(b)
    add_config_args(b)
    add_json_arg(b)
    b.set_defaults(func=build)
    i = msub.add_parser("info", help="nodes, edges, storage and unmapped openings of a map")
    i.add_argument("map", type=Path)
    add_config_args(i)  # planner.openings: what counts as an unmapped opening
    add_json_arg(i)
    i.set_defaults(func=info)
    pl = msub.add_parser("plot", help="top-down PNG of nodes and both edge sets over the occupancy grid")
    pl.add_argument("map", type=Path)
    pl.add_argument("-o", "--output", type=Path, required=True, help="PNG to write")
    pl.set_defaults(func=plot)
    from litevloc.cli.map_diff import add_diff_parser

    add_diff_parser(msub)
    from litevloc.cli.map_merge import add_merge_parser

    add_merge_parser(msub)
    from litevloc.cli.map_update import add_update_parser

    add_update_parser(msub)
    from litevloc.cli.map_fleet import add_fleet_parsers

    add_fleet_parsers(msub)


def info(args: argparse.Namespace) -> int:
    m = load_map(args.map)
    s = storage_summary(args.map)
    b = {k: v for k, v in m.meta.items() if k.startswith(("keyframe_", "build_")) or k == "poses"}
    data = {
        "nodes": m.n_nodes, "covisibility_edges": len(m.covis_edges), "connectivity_edges": len(m.conn_edges),
        "extractor": m.extractor, "vpr_model": m.vpr_model, "vpr_dim": int(m.vpr.shape[1]),
        "keypoints_per_node": float(sum(len(f.keypoints) for f in m.features) / m.n_nodes),
        "connectivity_metres_total": float(m.conn_metres.sum()), "grid_cells": list(m.grid.cells.shape),
        "grid_resolution_m": m.grid.resolution, **s,
        "build": b,
    }
    print(f"{args.map}: {m.n_nodes} nodes, {len(m.covis_edges)} covisibility edges, "
          f"{len(m.conn_edges)} connectivity edges ({data['connectivity_metres_total']:.1f} m); "
          f"features {m.extractor} ({data['keypoints_per_node']:.0f}/node), VPR {m.vpr_model} ({data['vpr_dim']}-d)")
    print_storage(s)
    if b:
        print(f"keyframes: coverage {b.get('keyframe_coverage')} (target {b.get('keyframe_coverage_target')}), "
              f"budget {b.get('keyframe_budget')}{' (BOUND)' if b.get('keyframe_budget_bound') == 'True' else ''}, "
              f"built in {b.get('build_seconds')} s from {b.get('build_frames')} frames")
    data["unmapped_openings"] = print_openings(m, config_of(args).planner.openings)
    write_json(args.json, data)
    return 0


def plot(args: argparse.Namespace) -> int:
    m = load_map(args.map)
    out = plot_map(m, args.output, title=f"{args.map.name}: {m.n_nodes} keyframes")
    print(f"wrote {out}")
    return 0
