"""`litevloc bench fusion [SRC] [--frames A:B] [--json PATH]`: the paper's Tables II/III shape.

On a posed sequence (default: the 7-Scenes query pass, frames 500-999, 30 Hz) with
seeded drift odometry at 100 Hz and simulated 1 Hz VLoc (10 % gross outliers, late by
0.1-1 s), prints ATE and output rate of odometry alone, VLoc alone, online fusion and
batch refinement, with and without robust kernels/gating; `--synthetic-minutes M` adds
the synthetic endurance run (update-time percentiles, graph size, RSS). See
`litevloc.pipelines.fusion.experiment` for the exact inputs.
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

from litevloc.runtime.cli.common import (
    add_config_args,
    add_json_arg,
    config_of,
    progress,
    write_json,
)

DEFAULT_SRC = Path("..") / "shared" / "data" / "7scenes-redkitchen"


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("fusion", help="fusion accuracy (ATE) and rates on a posed sequence")
    p.add_argument(
        "src",
        nargs="?",
        type=Path,
        default=None,
        help=f"posed dataset folder (7-Scenes or TUM RGB-D; default {DEFAULT_SRC})",
    )
    p.add_argument(
        "--frames",
        default="500:1000",
        metavar="A:B",
        help="frames of SRC to use, a Python slice (default 500:1000, the query pass)",
    )
    p.add_argument(
        "--seeds",
        type=int,
        default=5,
        help="odometry/VLoc seeds 0..N-1; medians reported (default 5)",
    )
    p.add_argument(
        "--synthetic-minutes",
        type=float,
        default=0.0,
        metavar="M",
        help="also run the synthetic endurance test for M minutes (0 = skip)",
    )
    p.add_argument(
        "--tum-dir",
        type=Path,
        default=None,
        metavar="DIR",
        help="write seed 0's trajectories here as TUM files (for evo and plots)",
    )
    add_config_args(p)
    add_json_arg(p)
    p.set_defaults(func=run)


def _table(res: dict) -> str:
    a = res["ate_m_all"]
    r = res["rate_hz"]
    lines = [
        f"{'method':<34}{'ATE RMSE [m]':>14}{'rate [Hz]':>11}",
        f"{'odometry alone':<34}{a['odometry']:>14.3f}{r['odometry']:>11.1f}",
        f"{'VLoc alone (10% outliers)':<34}{a['vloc_robust']:>14.3f}{r['vloc']:>11.2f}",
        f"{'VLoc alone (no outliers)':<34}{a['vloc_outlier_free']:>14.3f}{r['vloc']:>11.2f}",
    ]
    labels = {
        "robust": "kernel+gate, 10% outliers",
        "no_robust": "no kernel/gate, 10% outliers",
        "kernel_only": "kernel only, 10% outliers",
        "gate_only": "gate only, 10% outliers",
        "outlier_free": "kernel+gate, no outliers",
    }
    for kind, rate in (("fused", r["fused"]), ("batch", r["batch"])):
        for v, lab in labels.items():
            lines.append(f"{(kind + ' ' + lab):<34}{a[f'{kind}_{v}']:>14.3f}{rate:>11.1f}")
    return "\n".join(lines)


def _long_table(lr: dict) -> str:
    nan = float("nan")
    lines = [
        f"synthetic {lr['minutes']:g} min: {lr['odometry_messages']} odometry"
        f" -> {lr['fused_outputs']} fused, {lr['vloc_results']} VLoc;"
        f" ATE fused {lr['fused_ate_m']:.3f} m, odometry alone {lr['odometry_ate_m']:.3f} m",
        "call times in ms (wall; cpu = thread CPU time, immune to preemption by other processes)",
        f"{'minutes':<12}{'odo p50':>9}{'odo p99':>9}{'odo max':>9}{'odo cpu p99':>12}"
        f"{'vloc p99':>10}{'vloc cpu p99':>13}{'states':>8}",
    ]
    for b in lr["blocks"]:
        vp = b["vloc_call_ms_p99"]
        vc = b["vloc_cpu_ms_p99"]
        lines.append(
            f"{b['minutes'][0]:>4.1f}-{b['minutes'][1]:<7.1f}{b['odometry_call_ms_p50']:>9.3f}"
            f"{b['odometry_call_ms_p99']:>9.3f}{b['odometry_call_ms_max']:>9.2f}"
            f"{b['odometry_cpu_ms_p99']:>12.3f}{(vp if vp is not None else nan):>10.3f}"
            f"{(vc if vc is not None else nan):>13.3f}{b['states_max']:>8d}"
        )
    la = lr["load_average_1min"]
    lines.append(
        f"all calls p99 {lr['all_calls_ms_p99']:.3f} ms wall,"
        f" {lr['all_calls_cpu_ms_p99']:.3f} ms cpu;"
        f" states max {lr['states_in_graph_max']}; RSS {lr['rss_mib_start']:.1f} ->"
        f" {lr['rss_mib_end']:.1f} MiB; load average {la[0]:.1f} -> {la[1]:.1f}"
    )
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    from litevloc.pipelines.fusion.experiment import (
        VARIANTS,
        long_run_experiment,
        posed_sequence_experiment,
    )
    from litevloc.runtime.cli.common import frames_of
    from litevloc.runtime.cli.main import UserError
    from litevloc.runtime.sources import open_source

    cfg = config_of(args)
    if args.seeds < 1:
        raise UserError("--seeds must be >= 1")
    src_path = args.src if args.src is not None else DEFAULT_SRC
    src = open_source(src_path, frames_of(args), rgbd_calibration=cfg.rgbd_calibration)
    if not hasattr(src, "ground_truth"):
        raise UserError(f"{src_path}: needs ground-truth poses (a posed dataset folder)")
    gt_t, T_wc = src.ground_truth()
    if len(gt_t) < 10:
        raise UserError(
            f"{src_path} with --frames {args.frames}: only {len(gt_t)} ground-truth poses"
            " (need >= 10)"
        )
    params = cfg.fusion.params
    with progress(args.seeds * len(VARIANTS), "bench fusion", unit="run") as bar:
        res = posed_sequence_experiment(
            gt_t,
            T_wc,
            cfg.fusion.T_base_camera(),
            params,
            seeds=args.seeds,
            drift=cfg.odometry_sim.drift,
            progress=lambda: bar.update(1),
            tum_dir=args.tum_dir,
        )
    res["source"] = src.name
    res["frames"] = args.frames
    print(
        f"fusion on {src.name} frames {args.frames} ({res['duration_s']:.1f} s),"
        f" median of {args.seeds} seeds"
    )
    print(_table(res))
    t = res["timing"]
    print(
        f"online add_odometry p50/p99: {t['fused_robust_odometry_call_ms_p50']:.3f}/"
        f"{t['fused_robust_odometry_call_ms_p99']:.3f} ms"
        f" (cpu p99 {t['fused_robust_odometry_cpu_ms_p99']:.3f} ms);"
        f" batch solve {t['batch_robust_seconds']:.2f} s"
    )
    out = {**res}
    if args.synthetic_minutes > 0:
        n_msgs = int(args.synthetic_minutes * 60 * 100)
        with progress(n_msgs, f"synthetic {args.synthetic_minutes:g} min", unit="msg") as bar:
            lr = long_run_experiment(args.synthetic_minutes, params, progress=bar.update)
        out["synthetic"] = lr
        print(_long_table(lr))
    out["fusion_params"] = dataclasses.asdict(params)
    write_json(args.json, out)
    return 0
