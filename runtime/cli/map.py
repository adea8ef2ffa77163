"""`litevloc map build|info|plot`: build a map-lite topo-metric map and inspect it."""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

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
    i = msub.add_parser("info", help="nodes, edges, storage and unmapped openings of a map")
    i.add_argument("map", type=Path)
    add_config_args(i)  # planner.openings: what counts as an unmapped opening
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
    builder = MapBuilder(cfg.mapping, bundle.extract, bundle.describe, bundle.match, bundle.extractor.name,
                         bundle.vpr.name)
    t0 = time.perf_counter()
    cpu0 = _cpu_s()
    missing_pose = 0
    if str(args.src).startswith("sim:"):
        t1 = _build_passes_sim(args, cfg, builder)
    else:
        src = source_of(args, cfg)
        with progress(src.frame_count(), "map build: pass 1 (poses, depth)") as bar:
            for frame, T in posed_frames(src):
                bar.update(1)
                if T is None:
                    missing_pose += 1
                    continue
                builder.add(frame.t_ns, None, frame.depth, frame.K, T, frame.index)
        if builder.report.frames == 0:
            raise UserError(f"{args.src}: no frame had a ground-truth pose; a map needs posed images")
        want = _select(builder, cfg)
        t1 = time.perf_counter()
        with progress(len(want), "map build: pass 2 (keyframe features)") as bar:
            for frame, T in posed_frames(source_of(args, cfg)):
                pos = want.get(frame.index)
                if T is None or pos is None or builder.candidates[pos].features is not None:
                    continue
                if frame.depth is None:
                    raise UserError(f"{args.src}: frame {frame.index} lost its depth between the passes")
                builder.attach(pos, frame.color, frame.depth, frame.color_jpeg)
                bar.update(1)
    sel = builder.select()
    t1b = time.perf_counter()
    with progress(builder.n_covisibility_pairs(sel), "map build: covisibility", unit="pair") as bar:
        try:
            topomap = builder.finish(on_pair=lambda: bar.update(1), selected=sel)
        except ValueError as exc:
            raise UserError(f"{args.src}: {exc}") from exc
    t2 = time.perf_counter()
    cpu_s = _cpu_s() - cpu0
    r = builder.report
    topomap.meta.update({"source": str(args.src), "frames": args.frames or ":", "config": str(args.config),
                         # how the keyframes were chosen, kept with the map (map info, sim navigate JSON)
                         "keyframe_coverage": f"{r.coverage:.4f}",
                         "keyframe_coverage_target": str(cfg.mapping.keyframes.coverage),
                         "keyframe_budget": str(r.budget), "keyframe_budget_bound": str(r.budget_bound),
                         "keyframe_candidates": str(r.candidates), "build_frames": str(r.frames),
                         "build_seconds": f"{t2 - t0:.1f}"})
    save_map(topomap, args.output, overwrite=args.force, descriptor_bytes=cfg.mapping.descriptor_bytes)
    storage = storage_summary(args.output)
    summary = {
        "map": str(args.output), "frames": r.frames, "frames_without_pose": missing_pose,
        "candidates": r.candidates, "nodes": topomap.n_nodes, "coverage": r.coverage,
        "covisibility_edges": len(topomap.covis_edges), "connectivity_edges": len(topomap.conn_edges),
        "covisibility_pairs_checked": r.covisibility_pairs_checked,
        "seconds_frames": t1 - t0, "seconds_features": t1b - t1, "seconds_graph": t2 - t1b,
        "seconds": t2 - t0, "seconds_per_keyframe": (t2 - t0) / max(topomap.n_nodes, 1),
        # CPU seconds of this process (all threads): the cost on a machine shared with other jobs
        "cpu_seconds": cpu_s, "cpu_seconds_per_keyframe": cpu_s / max(topomap.n_nodes, 1),
        "keyframe_budget": r.budget, "budget_bound": r.budget_bound,
        "keyframe_coverage_target": cfg.mapping.keyframes.coverage,
        "candidate_key_bytes": r.candidate_key_bytes, "occupancy_voxel_bytes": r.voxel_bytes,
        "peak_rss_mb": round(peak_rss_mb(), 1), "skipped": r.skipped, **storage,
    }
    print(f"built {args.output}: {topomap.n_nodes} keyframes from {r.frames} frames ({r.candidates} candidates), "
          f"coverage {100 * r.coverage:.1f} %, {len(topomap.covis_edges)} covisibility + "
          f"{len(topomap.conn_edges)} connectivity edges in {t2 - t0:.1f} s "
          f"({summary['seconds_per_keyframe']:.2f} s/keyframe wall, "
          f"{summary['cpu_seconds_per_keyframe']:.2f} s/keyframe CPU, peak RSS {summary['peak_rss_mb']:.0f} MB)"
          + (f"; budget {r.budget} BINDS" if r.budget_bound else ""))
    _print_storage(storage)
    summary["unmapped_openings"] = _print_openings(topomap, cfg.planner.openings)
    write_json(args.json, summary)
    return 0


def _print_openings(m: Any, params: Any) -> list[dict[str, object]]:
    """List the unmapped openings of the map's occupancy grid (where to go back); their rows."""
    from litevloc.pipelines.topomap.openings import find_openings, openings_summary

    rows = openings_summary(find_openings(m.grid, params))
    print(f"unmapped openings: {len(rows)}" + ("" if rows else " (every opening of the grid was entered)"))
    for r in rows:
        print(f"  at ({r['x']:.1f}, {r['y']:.1f}) m, {r['width_m']:.1f} m wide, leading "
              f"({r['direction'][0]:+.2f}, {r['direction'][1]:+.2f}, {r['direction'][2]:+.2f}) into "
              f"{r['unknown_m2']:.1f} m^2 never seen")
    return rows


def _select(builder: MapBuilder, cfg: Any) -> dict[int, int]:
    builder.select()
    if builder.report.budget_bound:
        print(f"map build: the keyframe budget ({builder.report.budget}) binds: coverage "
              f"{100 * builder.report.coverage:.1f} % < target "
              f"{100 * cfg.mapping.keyframes.coverage:.0f} %", flush=True)
    return builder.wanted()


def _build_passes_sim(args: argparse.Namespace, cfg: Any, builder: MapBuilder) -> float:
    """Both passes straight from a simulated pass (`sim:WORLD?pass=map...`, the config's `sim`
    camera): pass 1 renders depth only, pass 2 renders colour for the keyframes only; no
    recording, no JPEG round trip. Returns the time pass 1 ended."""
    from litevloc.sim.source import open_sim_source

    if args.frames:
        raise UserError("--frames does not apply to a simulator source (use sim:WORLD?duration=S)")
    try:
        src = open_sim_source(str(args.src), cfg.sim)
    except ValueError as exc:
        raise UserError(str(exc)) from exc
    K = src.params.intrinsics.K
    poses = src.camera_poses()
    with progress(src.frame_count(), "map build: pass 1 (simulated depth)") as bar:
        for i, t in enumerate(src.frame_times):
            if builder.is_candidate(poses[i]):  # depth is rendered for candidates only
                builder.add(int(t), None, src.depth(i), K, poses[i], i)
            else:
                builder.add_pose(poses[i], i)
            bar.update(1)
    want = _select(builder, cfg)
    t1 = time.perf_counter()
    with progress(len(want), "map build: pass 2 (keyframe features)") as bar:
        for i, pos in sorted(want.items()):
            f = src.frame(i)
            assert f.depth is not None
            builder.attach(pos, f.color, f.depth, None)
            bar.update(1)
    return t1


def _cpu_s() -> float:
    import resource

    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def peak_rss_mb() -> float:
    """Peak resident set size of this process so far (MB; Linux ru_maxrss is in KB)."""
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _print_storage(s: dict[str, int]) -> None:
    print(f"storage: graph {s['graph_bytes'] / 1e3:.1f} KB + descriptors {s['descriptor_bytes'] / 1e3:.1f} KB, "
          f"features {s['feature_bytes'] / 1e6:.2f} MB, images {s['image_bytes'] / 1e6:.2f} MB")


def info(args: argparse.Namespace) -> int:
    m = load_map(args.map)
    s = storage_summary(args.map)
    b = {k: v for k, v in m.meta.items() if k.startswith(("keyframe_", "build_"))}
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
    _print_storage(s)
    if b:
        print(f"keyframes: coverage {b.get('keyframe_coverage')} (target {b.get('keyframe_coverage_target')}), "
              f"budget {b.get('keyframe_budget')}{' (BOUND)' if b.get('keyframe_budget_bound') == 'True' else ''}, "
              f"built in {b.get('build_seconds')} s from {b.get('build_frames')} frames")
    data["unmapped_openings"] = _print_openings(m, config_of(args).planner.openings)
    write_json(args.json, data)
    return 0


def plot(args: argparse.Namespace) -> int:
    m = load_map(args.map)
    out = plot_map(m, args.output, title=f"{args.map.name}: {m.n_nodes} keyframes")
    print(f"wrote {out}")
    return 0
