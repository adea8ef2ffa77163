"""`litevloc localize MAP SRC -o TRAJ.txt`: offline VLoc on every frame of a recording.

Runs the state machine (GL at start-up and when lost, LL from the last accepted pose)
and writes one TUM line (`t tx ty tz qx qy qz qw`, T_map_camera) per accepted query.
Where the input has ground truth, errors of accepted poses are reported too.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from litevloc.base.geometry import relative_pose_error
from litevloc.cli.common import add_config_args, add_frames_arg, add_json_arg, config_of, source_of
from litevloc.pipelines.localization.vloc import VisualLocalizer
from litevloc.pipelines.topomap.io import load_map
from litevloc.runtime.tools.outputs import progress, write_json
from litevloc.runtime.tools.posed import posed_frames


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("localize", help="localize every frame of a recording against a map (offline)")
    p.add_argument("map", type=Path)
    p.add_argument("src", type=Path, help="dataset folder or .mcap recording")
    p.add_argument("-o", "--output", type=Path, required=True, help="TUM trajectory of accepted VLoc poses")
    add_frames_arg(p)
    add_config_args(p)
    add_json_arg(p)
    from litevloc.cli.run import add_view_args

    add_view_args(p)  # --view / --view-save
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from litevloc.pipelines.evaluation.reloc import inside_95_ellipsoids
    from litevloc.pipelines.evaluation.trajectory import write_tum
    from litevloc.runtime.vloc_models import check_map_models, load_bundle, second_look_for

    cfg = config_of(args)
    bundle = load_bundle(cfg.models)
    topomap = check_map_models(load_map(args.map), bundle)
    loc = VisualLocalizer(topomap, cfg.localization, bundle.extract, bundle.describe, bundle.match,
                          second_look=second_look_for(topomap, cfg.models, cfg.localization, bundle))
    src = source_of(args, cfg)
    from litevloc.cli.run import make_view

    view = make_view(args, topomap)  # None unless --view / --view-save
    times: list[float] = []
    poses: list = []
    errors: list[tuple[float, float]] = []
    inside: list[tuple[bool, bool]] = []  # error inside the pose's own 95 % ellipsoid (position, rotation)
    n_keyframes: list[int] = []
    lat: dict[str, list[float]] = {"global": [], "local": []}
    stages: dict[str, list[dict[str, float]]] = {"global": [], "local": []}  # per mode: stage ms of each query
    counts = {"queries": 0, "accepted": 0, "rejected": 0, "global": 0, "local": 0}
    reasons: dict[str, int] = {}
    with progress(src.frame_count(), "localize") as bar:
        for frame, T_gt in posed_frames(src):
            bar.update(1)
            res = loc.process(frame.t_ns, frame.color, frame.depth, frame.K)
            if view is not None:
                view.put_vloc(frame, res)
                view.put_status({"sensor_time_ns": frame.t_ns, "state": str(loc.tracker.state),
                                 "reasons": [res.reason]})
            counts["queries"] += 1
            counts[res.mode] += 1
            lat[res.mode].append(res.timings_ms.get("total", 0.0))
            stages[res.mode].append(dict(res.timings_ms))
            if res.accepted and res.T_map_camera is not None:
                counts["accepted"] += 1
                times.append(frame.t_ns * 1e-9)
                poses.append(res.T_map_camera)
                n_keyframes.append(len(res.keyframes))
                if T_gt is not None:
                    errors.append(relative_pose_error(res.T_map_camera, T_gt))
                    if res.covariance is not None:
                        inside.append(inside_95_ellipsoids(res.T_map_camera, T_gt, res.covariance))
            else:
                counts["rejected"] += 1
                key = res.reason.split("(")[0].strip()
                reasons[key] = reasons.get(key, 0) + 1
    if view is not None:
        print(f"view: {view.close()}")
    args.output.parent.mkdir(parents=True, exist_ok=True)
    write_tum(args.output, np.array(times), np.array(poses).reshape(-1, 4, 4))
    summary: dict = {**counts, "rejection_reasons": reasons, "output": str(args.output),
                     "transitions": [f"{t.from_state}->{t.to_state}: {t.reason}" for t in loc.tracker.transitions]}
    for mode, v in lat.items():
        if v:
            summary[f"{mode}_latency_ms"] = {"median": float(np.median(v)), "p90": float(np.percentile(v, 90))}
            # mean ms per query of each stage (0 where a query skipped it; "match" sums all candidates)
            keys = sorted({k for q in stages[mode] for k in q})
            summary[f"{mode}_stage_mean_ms"] = {k: float(np.mean([q.get(k, 0.0) for q in stages[mode]])) for k in keys}
    if errors:
        e = np.array(errors)
        summary["errors"] = {
            "median_m": float(np.median(e[:, 0])), "median_deg": float(np.median(e[:, 1])),
            "max_m": float(e[:, 0].max()), "max_deg": float(e[:, 1].max()),
            "within_25cm_5deg": float(np.mean((e[:, 0] < 0.25) & (e[:, 1] < 5))),
        }
        if inside:
            c = np.array(inside)
            summary["covariance_calibration"] = {"position_inside_95": float(c[:, 0].mean()),
                                                 "rotation_inside_95": float(c[:, 1].mean())}
    if n_keyframes:
        summary["keyframes_per_pose_mean"] = float(np.mean(n_keyframes))
    _print_summary(summary, counts, args.output)
    write_json(args.json, summary)
    return 0


def _print_summary(summary: dict, counts: dict[str, int], output: Path) -> None:
    """The run's result in a line (accepted queries, errors, covariance calibration), then each
    mode's latency and mean stage times."""
    line = (f"localized {counts['accepted']}/{counts['queries']} queries "
            f"({counts['global']} global, {counts['local']} local) -> {output}")
    if "errors" in summary:
        er = summary["errors"]
        line += (f"; error median {100 * er['median_m']:.1f} cm / {er['median_deg']:.2f} deg, "
                 f"max {100 * er['max_m']:.1f} cm")
        if "covariance_calibration" in summary:
            cc = summary["covariance_calibration"]
            line += (f"; inside own 95 % ellipsoid: position {100 * cc['position_inside_95']:.0f} %, "
                     f"rotation {100 * cc['rotation_inside_95']:.0f} %")
    print(line)
    for mode in ("global", "local"):
        if f"{mode}_latency_ms" in summary:
            s = summary[f"{mode}_latency_ms"]
            parts = ", ".join(f"{k} {v:.0f}" for k, v in summary[f"{mode}_stage_mean_ms"].items() if k != "total")
            print(f"  {mode} latency: median {s['median']:.0f} ms, p90 {s['p90']:.0f} ms (mean ms: {parts})")
