"""Building a map from a recording, dataset or simulated pass: what `litevloc map build` runs.

Where the keyframe poses come from (`--poses`):

* `ground-truth`: the source's ground truth (datasets, simulator, recordings with
  /ground_truth/camera_pose);
* `odometry`: the recording's /odom alone, interpolated at each frame (no loop closure: the
  honest baseline of what SLAM adds);
* `slam`: the mapping pass's own pose-graph SLAM (`pipelines.slam`): odometry and visual
  edges, loop closures verified like localization, robust optimisation. Never reads ground
  truth while building; with ground truth in the source, errors are reported afterwards;
* `FILE`: a TUM trajectory (`t x y z qx qy qz qw`, seconds in the recording's clock) from an
  external SLAM, of the camera or of base_link (`--poses-frame`); frames outside it, or in a
  longer gap than `slam.file_max_gap_s`, are skipped and counted;
* `auto` (default): ground truth where the source has it, else `slam`.

The map is then built by `pipelines.topomap.build.MapBuilder` from those poses, so every
downstream command reads it as any other map.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from litevloc.base.errors import LiteVLocError
from litevloc.base.frames import parse_frames
from litevloc.base.process_usage import cpu_seconds, peak_rss_mb
from litevloc.config.schema import LiteVLocConfig
from litevloc.hw.messages import EncodedRgbdFrame, Message, RgbdFrame
from litevloc.hw.streams.base import StreamSource
from litevloc.pipelines.slam.frames import interpolate_trajectory
from litevloc.pipelines.slam.session import SlamError, map_frame
from litevloc.pipelines.topomap.build import MapBuilder
from litevloc.pipelines.topomap.io import storage_summary
from litevloc.pipelines.topomap.map_save import save_map
from litevloc.runtime.tools.outputs import progress
from litevloc.runtime.tools.posed import odometry_posed_frames, posed_frames, trajectory_posed_frames

PoseSource = str  # "ground-truth" | "odometry" | "slam" | "file"
Posed = Iterator[tuple[RgbdFrame | EncodedRgbdFrame, NDArray[np.float64] | None]]


class MapBuildError(LiteVLocError):
    """The input cannot make a map (no pose source, no posed frame, a missing file); the
    message names the input."""


@dataclasses.dataclass(frozen=True)
class MapBuildRequest:
    """What to build a map from and where to write it (the `litevloc map build` arguments)."""

    # dataset folder, .mcap recording or simulator URI (`sim:WORLD?pass=map`)
    src: str | Path
    # map folder to write
    output: Path
    # replace an existing map folder
    force: bool = False
    # part of a recording or dataset: a Python slice over frame indices ("A:B"); None: all
    frames: str | None = None
    # keyframe poses: auto, ground-truth, odometry, slam or a TUM trajectory file
    poses: str = "auto"
    # a trajectory file's poses are of the "camera" optical frame or of "base_link"
    poses_frame: str = "camera"
    # poses slam: also write the pose graph here (.npz)
    slam_graph: Path | None = None
    # the configuration's name or file, kept in the map's metadata
    config: str | None = None


def build_map(req: MapBuildRequest, cfg: LiteVLocConfig) -> dict[str, Any]:
    """Build the map `req` asks for with `cfg` and write it; returns the build summary (what
    `map build --json` writes). MapBuildError (or another LiteVLocError) names what is wrong."""
    from threadpoolctl import threadpool_limits

    # one BLAS thread: the build's matrix products are small (keypoints x keypoints, 6x6 solves),
    # where waking OpenBLAS's threads costs more than the work (SLAM front end 4x faster on 2 cores)
    with threadpool_limits(limits=1, user_api="blas"):
        return _build(req, cfg)


def _open_recording(req: MapBuildRequest, cfg: LiteVLocConfig) -> StreamSource:
    """`req.src` opened strictly, limited to `req.frames`, with the config's RGB-D calibration."""
    from litevloc.runtime.sources import open_source

    try:
        frames = parse_frames(req.frames)
    except ValueError as exc:
        raise MapBuildError(str(exc)) from exc
    return open_source(req.src, frames, strict=True, rgbd_calibration=cfg.rgbd_calibration)


def _has(src: Any, what: str) -> bool:
    """Whether a source has ground truth ("gt") or odometry ("odom")."""
    from litevloc.hw.streams.mcap_io import TOPIC_GT, TOPIC_ODOM, McapSource

    if isinstance(src, McapSource):
        return src.topic_counts.get(TOPIC_GT if what == "gt" else TOPIC_ODOM, 0) > 0
    if hasattr(src, "run"):  # a simulated pass has both
        return True
    return what == "gt"  # dataset folders: posed, no odometry


def pose_source(req: MapBuildRequest, src: Any) -> tuple[PoseSource, Path | None]:
    """Resolve `--poses` for this source; MapBuildError naming what is missing."""
    p = str(req.poses)
    if p == "auto":
        return ("ground-truth" if _has(src, "gt") else "slam"), None
    if p in ("ground-truth", "slam"):
        if p == "ground-truth" and not _has(src, "gt"):
            raise MapBuildError(f"{req.src}: no ground-truth poses (/ground_truth/camera_pose); use --poses slam")
        return p, None
    if p == "odometry":
        if not _has(src, "odom"):
            raise MapBuildError(f"{req.src}: no odometry (/odom) to pose the map with; use --poses slam")
        return p, None
    path = Path(p)
    if not path.is_file():
        raise MapBuildError(f"--poses {p}: not auto, ground-truth, odometry, slam nor a trajectory file")
    return "file", path


def _file_trajectory(path: Path, frame: str, cfg: Any) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """(ns stamps, camera poses) of a TUM file (`--poses-frame base_link`: moved to the camera)."""
    from litevloc.pipelines.evaluation.trajectory import TrajectoryError, read_tum

    try:
        t, P = read_tum(path)
    except TrajectoryError as exc:
        raise MapBuildError(str(exc)) from exc
    if frame == "base_link":
        P = P @ cfg.fusion.T_base_camera()
    return np.round(t * 1e9).astype(np.int64), P


def _odometry_in_map(posed: Posed, cfg: Any) -> Posed:
    """Odometry camera poses moved into the SLAM's map frame convention (first posed frame's
    base_link, levelled by the odometry frame, gravity along mapping.up)."""
    T_bc = cfg.fusion.T_base_camera()
    T_map_odom = None
    for frame, T in posed:
        if T is not None and T_map_odom is None:
            T_first, _ = map_frame(T @ np.linalg.inv(T_bc), T_bc, cfg.mapping.up)
            T_map_odom = T_first @ np.linalg.inv(T)
        yield frame, (None if T is None or T_map_odom is None else T_map_odom @ T)


def posed_stream(kind: PoseSource, messages: Iterable[Message], cfg: Any, traj: Any) -> Posed:
    """(frame, T_map_camera or None) for a non-SLAM pose source. A recording's frames come with
    their colour still encoded (`EncodedRgbdFrame`): pass 1 reads depth only and pass 2 decodes
    the keyframes' colour alone (decoding every frame twice was a sixth of a build's time)."""
    from litevloc.hw.streams.mcap_io import McapSource

    if isinstance(messages, McapSource):
        lean = messages.messages(defer_color=True, skip_odometry=kind != "odometry")
        if kind == "ground-truth":
            return posed_frames(lean, frame_type=EncodedRgbdFrame)
        if kind == "odometry":
            odo = odometry_posed_frames(lean, cfg.fusion.T_base_camera(), frame_type=EncodedRgbdFrame)
            return _odometry_in_map(odo, cfg)
        return trajectory_posed_frames(lean, traj[0], traj[1], int(cfg.slam.file_max_gap_s * 1e9),
                                       frame_type=EncodedRgbdFrame)
    if kind == "ground-truth":
        return posed_frames(messages)
    if kind == "odometry":
        return _odometry_in_map(odometry_posed_frames(messages, cfg.fusion.T_base_camera()), cfg)
    return trajectory_posed_frames(messages, traj[0], traj[1], int(cfg.slam.file_max_gap_s * 1e9))


def sim_poses(kind: PoseSource, src: Any, cfg: Any, traj: Any) -> list[NDArray[np.float64] | None]:
    """Camera poses at a simulated pass's frame times for a non-SLAM pose source."""
    if kind == "ground-truth":
        return list(src.camera_poses())
    times = [int(t) for t in src.frame_times]
    if kind == "file":
        return interpolate_trajectory(traj[0], traj[1], times, int(cfg.slam.file_max_gap_s * 1e9))
    T_bc = cfg.fusion.T_base_camera()
    odo = interpolate_trajectory(src.run.t_ns, src.run.T_odom_base, times, int(1e18))
    first = next((T for T in odo if T is not None), None)
    if first is None:
        return odo
    T_first, _ = map_frame(first, T_bc, cfg.mapping.up)
    T_map_odom = T_first @ np.linalg.inv(first @ T_bc)
    return [None if T is None else T_map_odom @ T @ T_bc for T in odo]


def two_passes(req: MapBuildRequest, cfg: Any, builder: MapBuilder, kind: PoseSource, traj: Any) -> int:
    """Pass 1 (poses + depth) and pass 2 (keyframe features) over a recording or dataset.
    Returns the frames without a pose."""
    src = _open_recording(req, cfg)
    missing = 0
    with progress(src.frame_count(), "map build: pass 1 (poses, depth)") as bar:
        for frame, T in posed_stream(kind, src, cfg, traj):
            bar.update(1)
            if T is None:
                missing += 1
                continue
            builder.add(frame.t_ns, None, frame.depth, frame.K, T, frame.index)
    if builder.report.frames == 0:
        what = {"ground-truth": "a ground-truth pose", "odometry": "an odometry pose",
                "file": "a pose in the trajectory file (same clock as the recording?)"}[kind]
        raise MapBuildError(f"{req.src}: no frame had {what}; a map needs posed images")
    want = select_keyframes(builder, cfg)
    with progress(len(want), "map build: pass 2 (keyframe features)") as bar:
        for frame, T in posed_stream(kind, _open_recording(req, cfg), cfg, traj):
            pos = want.get(frame.index)
            if T is None or pos is None or builder.candidates[pos].features is not None:
                continue
            if isinstance(frame, EncodedRgbdFrame):
                frame = frame.decode()  # StreamError naming the frame if its colour is corrupt
            if frame.depth is None:
                raise MapBuildError(f"{req.src}: frame {frame.index} lost its depth between the passes")
            builder.attach(pos, frame.color, frame.depth, frame.color_jpeg)
            bar.update(1)
    return missing


def select_keyframes(builder: MapBuilder, cfg: Any) -> dict[int, int]:
    builder.select()
    if builder.report.budget_bound:
        print(f"map build: the keyframe budget ({builder.report.budget}) binds: coverage "
              f"{100 * builder.report.coverage:.1f} % < target "
              f"{100 * cfg.mapping.keyframes.coverage:.0f} %", flush=True)
    return builder.wanted()


def sim_passes(builder: MapBuilder, cfg: Any, src: Any, poses: list[NDArray[np.float64] | None]) -> int:
    """Both passes straight from a simulated pass (the config's `sim` camera): pass 1 renders
    depth only and only for candidates, pass 2 renders colour for the keyframes; no recording,
    no JPEG round trip. Returns the frames without a pose."""
    K = src.params.intrinsics.K
    missing = 0
    with progress(src.frame_count(), "map build: pass 1 (simulated depth)") as bar:
        for i, t in enumerate(src.frame_times):
            bar.update(1)
            T = poses[i]
            if T is None:
                missing += 1
            elif builder.is_candidate(T):  # depth is rendered for candidates only
                builder.add(int(t), None, src.depth(i), K, T, i)
            else:
                builder.add_pose(T, i)
    want = select_keyframes(builder, cfg)
    with progress(len(want), "map build: pass 2 (keyframe features)") as bar:
        for i, pos in sorted(want.items()):
            f = src.frame(i)
            assert f.depth is not None
            builder.attach(pos, f.color, f.depth, None)
            bar.update(1)
    return missing


def open_build_source(req: MapBuildRequest, cfg: Any) -> Any:
    if not str(req.src).startswith("sim:"):
        return _open_recording(req, cfg)
    from litevloc.sim.source import open_sim_source

    if req.frames:
        raise MapBuildError("--frames does not apply to a simulator source (use sim:WORLD?duration=S)")
    try:
        return open_sim_source(str(req.src), cfg.sim)
    except ValueError as exc:
        raise MapBuildError(str(exc)) from exc


def slam_pass(req: MapBuildRequest, cfg: Any, bundle: Any, src: Any, builder: MapBuilder) -> tuple[Any, Any, int]:
    """The SLAM over the source (one pass), then both map-builder passes from its result.
    Returns (session, SlamPass, frames without a pose)."""
    from litevloc.runtime.tools.slam_build import feed_builder, new_session, run_on_messages, run_on_sim, slam_models

    session = new_session(cfg, slam_models(cfg, bundle), _has(src, "odom"))
    with progress(src.frame_count(), "map build: SLAM") as bar:
        try:
            if hasattr(src, "run"):
                sp = run_on_sim(session, src, lambda: bar.update(1))
            else:  # a recording's colour is decoded only for the frames the SLAM loads
                from litevloc.hw.streams.mcap_io import McapSource

                msgs = src.messages(defer_color=True) if isinstance(src, McapSource) else src
                sp = run_on_messages(session, msgs, lambda: bar.update(1))
        except SlamError as exc:
            raise MapBuildError(f"{req.src}: {exc}") from exc
    return session, sp, feed_builder(sp.result, builder)


def _build(req: MapBuildRequest, cfg: LiteVLocConfig) -> dict[str, Any]:
    from litevloc.models.registry import load_matcher
    from litevloc.runtime.vloc_models import load_bundle

    if req.output.exists() and not req.force:
        raise MapBuildError(f"{req.output} exists; pass --force to replace it")
    src = open_build_source(req, cfg)
    kind, path = pose_source(req, src)
    traj = _file_trajectory(path, req.poses_frame, cfg) if path is not None else None
    bundle = load_bundle(cfg.models, matcher=cfg.models.matcher if kind == "slam" else cfg.mapping.covisibility_matcher)
    covis = bundle if kind != "slam" else dataclasses.replace(
        bundle, matcher=load_matcher(cfg.mapping.covisibility_matcher, cfg.models))
    builder = MapBuilder(cfg.mapping, covis.extract, covis.describe, covis.match, bundle.extractor.name,
                         bundle.vpr.name)
    t0, cpu0 = time.perf_counter(), cpu_seconds()
    slam = None
    if kind == "slam":
        slam = slam_pass(req, cfg, bundle, src, builder)
        missing = slam[2]
    elif hasattr(src, "run"):
        missing = sim_passes(builder, cfg, src, sim_poses(kind, src, cfg, traj))
    else:
        missing = two_passes(req, cfg, builder, kind, traj)
    t1 = time.perf_counter()
    sel = builder.select()
    with progress(builder.n_covisibility_pairs(sel), "map build: covisibility", unit="pair") as bar:
        try:
            topomap = builder.finish(on_pair=lambda: bar.update(1), selected=sel)
        except ValueError as exc:
            raise MapBuildError(f"{req.src}: {exc}") from exc
    t2 = time.perf_counter()
    topomap.meta.update(_meta(req, cfg, builder, kind, t2 - t0))
    save_map(topomap, req.output, overwrite=req.force, descriptor_bytes=cfg.mapping.descriptor_bytes)
    t3 = time.perf_counter()
    summary = _summary(req, cfg, builder, topomap, missing, kind, (t0, t1, t2, t3), cpu_seconds() - cpu0)
    if slam is not None:
        summary["slam"] = _slam_report(req, slam, src, t3 - t1)
    _print_summary(req, builder, topomap, summary)
    summary["unmapped_openings"] = print_openings(topomap, cfg.planner.openings)
    return summary


def _meta(req: MapBuildRequest, cfg: Any, builder: MapBuilder, kind: PoseSource, seconds: float) -> dict[str, str]:
    r = builder.report
    return {"source": str(req.src), "frames": req.frames or ":", "config": str(req.config),
            # how the keyframes were chosen and posed, kept with the map (map info, sim navigate JSON)
            "poses": kind if kind != "file" else f"file:{req.poses} ({req.poses_frame})",
            "keyframe_coverage": f"{r.coverage:.4f}", "keyframe_coverage_target": str(cfg.mapping.keyframes.coverage),
            "keyframe_budget": str(r.budget), "keyframe_budget_bound": str(r.budget_bound),
            "keyframe_candidates": str(r.candidates), "build_frames": str(r.frames), "build_seconds": f"{seconds:.1f}"}


def _summary(req: MapBuildRequest, cfg: Any, builder: MapBuilder, topomap: Any, missing: int, kind: PoseSource,
             t: tuple[float, float, float, float], cpu_s: float) -> dict[str, Any]:
    r = builder.report
    storage = storage_summary(req.output)
    n = max(topomap.n_nodes, 1)
    return {
        "map": str(req.output), "poses": kind, "frames": r.frames, "frames_without_pose": missing,
        "candidates": r.candidates, "nodes": topomap.n_nodes, "coverage": r.coverage,
        "covisibility_edges": len(topomap.covis_edges), "connectivity_edges": len(topomap.conn_edges),
        "covisibility_pairs_checked": r.covisibility_pairs_checked,
        # poses (and, for slam, every keyframe's features) / graphs / writing the map folder
        "seconds_frames": t[1] - t[0], "seconds_graph": t[2] - t[1], "seconds_write": t[3] - t[2],
        "seconds": t[3] - t[0], "seconds_per_keyframe": (t[3] - t[0]) / n,
        # CPU seconds of this process (all threads): the cost on a machine shared with other jobs
        "cpu_seconds": cpu_s, "cpu_seconds_per_keyframe": cpu_s / n,
        "keyframe_budget": r.budget, "budget_bound": r.budget_bound,
        "keyframe_coverage_target": cfg.mapping.keyframes.coverage,
        "candidate_key_bytes": r.candidate_key_bytes, "occupancy_voxel_bytes": r.voxel_bytes,
        "peak_rss_mb": round(peak_rss_mb(), 1), "skipped": r.skipped, **storage,
    }


def _slam_report(req: MapBuildRequest, slam: tuple[Any, Any, int], src: Any, map_seconds: float
                 ) -> dict[str, Any]:
    """The SLAM's report, its map time, and (only now, after the build) its errors against the
    source's ground truth where it has one."""
    from litevloc.runtime.tools.slam_build import evaluate_against

    session, sp, _ = slam
    rep = dict(sp.result.report)
    if req.slam_graph is not None:
        from litevloc.runtime.tools.slam_build import save_graph

        save_graph(req.slam_graph, sp.result)
        rep["graph_file"] = str(req.slam_graph)
    rep["seconds"] = {**rep["seconds"], "map_write": round(map_seconds, 2)}  # map graphs + writing the folder
    rep["skipped"] = sp.skipped
    gt = sp.ground_truth
    if hasattr(src, "run"):  # the simulator's ground truth, read now
        gt = {int(t): T for t, T in zip(src.frame_times, src.camera_poses(), strict=True)}
    rep["evaluation"] = evaluate_against(session, sp.result, gt) if gt else {"reference": "none in the source"}
    return rep


def _print_summary(req: MapBuildRequest, builder: MapBuilder, topomap: Any, s: dict[str, Any]) -> None:
    r = builder.report
    print(f"built {req.output}: {topomap.n_nodes} keyframes from {r.frames} frames ({r.candidates} candidates), "
          f"coverage {100 * r.coverage:.1f} %, {len(topomap.covis_edges)} covisibility + "
          f"{len(topomap.conn_edges)} connectivity edges in {s['seconds']:.1f} s "
          f"({s['seconds_per_keyframe']:.2f} s/keyframe wall, "
          f"{s['cpu_seconds_per_keyframe']:.2f} s/keyframe CPU, peak RSS {s['peak_rss_mb']:.0f} MB)"
          + (f"; budget {r.budget} BINDS" if r.budget_bound else ""))
    if s["frames_without_pose"]:
        print(f"  {s['frames_without_pose']} frame(s) had no pose ({s['poses']}) and were skipped")
    print_storage(storage_summary(req.output))
    if "slam" in s:
        print_slam_report(s["slam"])


def print_openings(m: Any, params: Any) -> list[dict[str, object]]:
    """List the unmapped openings of the map's occupancy grid (where to go back); their rows."""
    from litevloc.pipelines.topomap.openings import find_openings, openings_summary

    rows = openings_summary(find_openings(m.grid, params))
    print(f"unmapped openings: {len(rows)}" + ("" if rows else " (every opening of the grid was entered)"))
    for r in rows:
        d: Any = r["direction"]
        print(f"  at ({r['x']:.1f}, {r['y']:.1f}) m, {r['width_m']:.1f} m wide, leading "
              f"({d[0]:+.2f}, {d[1]:+.2f}, {d[2]:+.2f}) into "
              f"{r['unknown_m2']:.1f} m^2 never seen")
    return rows


def print_storage(s: dict[str, int]) -> None:
    print(f"storage: graph {s['graph_bytes'] / 1e3:.1f} KB + descriptors {s['descriptor_bytes'] / 1e3:.1f} KB, "
          f"features {s['feature_bytes'] / 1e6:.2f} MB, images {s['image_bytes'] / 1e6:.2f} MB")


def print_slam_report(rep: dict[str, Any]) -> None:
    """The SLAM report in words."""
    lp, sec = rep["loops"], rep["seconds"]
    print(f"SLAM: {rep['keyframes']} keyframes ({rep['keyframes_in_map']} in the map), odometry: "
          f"{rep['odometry_source']}; up: {rep['up']}")
    print(f"  loops: {lp['candidates']} candidates, {lp['tried']} tried, {lp['verified']} verified, {lp['kept']} kept, "
          f"{sum(lp['rejected_by_gate'].values())} rejected by the consistency gate "
          f"({', '.join(f'{k} {v}' for k, v in lp['rejected_by_gate'].items()) or 'none'}), "
          f"{lp['rejected_by_optimiser']} by the optimiser")
    wl = rep.get("walls")
    if isinstance(wl, dict):
        print(f"  walls: {wl['observations']} planes seen, {wl['walls']} walls seen from several keyframes, "
              f"{wl['factors']} plane factors ({wl['outliers_dropped']} dropped as outliers)")
    print(f"  time: front end {sec['front_end']:.1f} s, loop search {sec['loop_search']:.1f} s, optimisation "
          f"{sec['optimisation']:.1f} s, map (graphs + write) {sec['map_write']:.1f} s")
    for f in rep["faults"]:
        print(f"  fault at {f['t_s']:.1f} s: {f['kind']}: {f['detail']} -> {f['handling']}")
    for w in rep["warnings"]:
        print(f"  warning: {w}")
    ev = rep.get("evaluation", {})
    if ev.get("keyframe_ate_m") is not None:
        odo = ev.get("odometry_ate_m")
        print(f"  against {ev['reference']}: keyframe ATE {100 * ev['keyframe_ate_m']:.1f} cm"
              + (f" (odometry alone {100 * odo:.1f} cm" if odo is not None else " (")
              + f", without loops {100 * (ev.get('no_loop_ate_m') or float('nan')):.1f} cm), wrong loops kept "
                f"{ev['wrong_loops_kept']} of {ev['wrong_loops']}")


