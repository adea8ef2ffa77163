"""`litevloc replay REC`: play a recording with its timing and summarise it."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from litevloc.cli.common import add_config_args, add_frames_arg, add_json_arg, config_of, frames_of
from litevloc.hw.messages import GroundTruthPose, Odometry, RgbdFrame
from litevloc.runtime.service.pacing import paced
from litevloc.runtime.sources import open_source
from litevloc.runtime.tools.outputs import progress, write_json


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("replay", help="play a recording (or dataset folder) with its recorded timing; with a map, "
                                      "through the onboard service")
    p.add_argument("rec", type=Path, help=".mcap recording (or dataset folder)")
    p.add_argument("-o", "--output", type=Path, default=None,
                   help="with a map: write the published fused trajectory (TUM, T_map_base) here")
    p.add_argument("--rate", type=float, default=None,
                   help="real-time factor (default from config: 1; 0 = as fast as possible)")
    add_frames_arg(p)
    add_config_args(p)
    from litevloc.cli.run import add_service_args

    add_service_args(p)
    add_json_arg(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    cfg = config_of(args)
    if args.map is not None or cfg.map:
        return run_runtime(args)
    rate = cfg.replay.rate if args.rate is None else args.rate
    if rate < 0:
        from litevloc.cli.main import UserError

        raise UserError("--rate must be >= 0")
    src = open_source(args.rec, frames_of(args), strict=False)
    counts = {"frames": 0, "odometry": 0, "ground_truth": 0}
    first = last = None
    t0 = time.perf_counter()
    with progress(src.frame_count(), "replay") as bar:
        for msg in paced(src, rate):
            first = msg.t_ns if first is None else first
            last = msg.t_ns
            if isinstance(msg, RgbdFrame):
                counts["frames"] += 1
                bar.update(1)
            elif isinstance(msg, Odometry):
                counts["odometry"] += 1
            elif isinstance(msg, GroundTruthPose):
                counts["ground_truth"] += 1
    wall = time.perf_counter() - t0
    sensor_s = 0.0 if first is None or last is None else (last - first) * 1e-9
    fps = counts["frames"] / max(wall, 1e-9)
    skipped = src.stats.skipped
    print(
        f"replayed {src.name}: {counts['frames']} frames, {counts['odometry']} odometry, "
        f"{counts['ground_truth']} ground-truth poses over {sensor_s:.2f} s of sensor time "
        f"in {wall:.2f} s wall ({fps:.1f} frames/s, rate {rate:g}); skipped {sum(skipped.values())}"
        + (f" {skipped}" if skipped else "")
    )
    write_json(args.json, {**counts, "sensor_seconds": sensor_s, "wall_seconds": wall, "frames_per_second": fps,
                           "rate": rate, "skipped": skipped, "source": src.name})
    return 0


def run_runtime(args: argparse.Namespace) -> int:
    """The full threaded runtime on the recording (hardware-in-the-loop replay)."""
    import numpy as np

    from litevloc.cli.run import run_service
    from litevloc.pipelines.evaluation.trajectory import write_tum

    res = run_service(args, args.rec, args.rate)
    rec = res["recorder"]
    status = res["status"]
    summary: dict = {"ok": res["ok"], "reason": res["reason"], "fused_poses": len(rec.fused_t)}
    if args.output is not None:  # written even when empty: an old file must not pass for this run's
        poses = np.stack(rec.fused_T) if rec.fused_t else np.zeros((0, 4, 4))
        write_tum(args.output, np.array(rec.fused_t, np.float64) * 1e-9, poses)
        summary["output"] = str(args.output)
    r = rec.camera_ate(res["T_base_camera"])
    if r is not None:
        summary["ate_m"] = {"rmse": r.rmse, "median": r.median, "max": r.max, "n": r.n}
    for key in ("state", "reasons", "counters", "last_vloc_reason", "last_fusion_reason", "vloc_state", "latency",
                "frames_dropped", "queues", "stages", "faults", "models"):
        if key in status:
            summary[key] = status[key]
    line = f"replay (runtime): {res['reason']}; {len(rec.fused_t)} fused poses"
    if not rec.fused_t:  # say why: fusion starts only on agreeing VLoc fixes
        line += (f" (fusion: {status.get('last_fusion_reason') or 'never started'}; "
                 f"last VLoc answer: {status.get('last_vloc_reason') or 'none'})")
    if "ate_m" in summary:
        a = summary["ate_m"]
        line += f"; camera ATE (no alignment) RMSE {100 * a['rmse']:.1f} cm, median {100 * a['median']:.1f} cm"
    print(line)
    write_json(args.json, summary)
    return 0 if res["ok"] else 1
