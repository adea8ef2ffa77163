"""The fusion benchmark (`litevloc bench fusion`, `bench/fusion.py`): pure functions on arrays, and
`run_benchmark` that feeds them a posed dataset.

`posed_sequence_experiment` reproduces the shape of the LiteVLoc paper's Tables II/III on
a posed sequence (ground-truth camera poses + times): ATE (m, after SE(3) alignment
without scale, translation) and output rate of odometry alone, VLoc alone, online fusion
(PS) and batch refinement (PS-Opt), with and without robust kernels/gating and with
and without gross VLoc outliers. Inputs per seed s (all seeded, documented):

* odometry: `odometry_drift.simulate_odometry(rate 100 Hz, DriftParams(), seed=s)` on
  the ground-truth base trajectory (`T_world_base = T_world_camera @ inv(T_base_camera)`);
* VLoc: `simulate.simulate_vloc` at 1 Hz from ground truth, noise = the FusionParams VLoc
  sigmas, outlier_ratio 0.1 (or 0), latency U(0.1, 1.0) s, seed = 1000 + s.

Numbers are medians over seeds. `long_run_experiment` is the synthetic endurance run:
update-time percentiles per block, graph size and RSS at start and end.
"""

from __future__ import annotations

import dataclasses
import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from litevloc.base.geometry import interpolate_pose_at, invert
from litevloc.base.params.drift import DriftParams
from litevloc.base.params.fusion import FusionParams
from litevloc.base.process_usage import memory_mb
from litevloc.config.schema import LiteVLocConfig
from litevloc.experiments.fusion_sim import run_online, simulate_vloc, synthetic_trajectory
from litevloc.pipelines.evaluation.trajectory import ate, write_tum
from litevloc.pipelines.fusion.batch import refine_session
from litevloc.pipelines.odometry_drift import simulate_odometry

F64 = NDArray[np.float64]

VARIANTS: dict[str, dict[str, Any]] = {
    # name: (outlier ratio, FusionParams overrides)
    "robust": {"outliers": 0.1, "params": {}},
    "no_robust": {"outliers": 0.1, "params": {"robust_kernel": "none", "gate_chi2": 0.0}},
    "kernel_only": {"outliers": 0.1, "params": {"gate_chi2": 0.0}},
    "gate_only": {"outliers": 0.1, "params": {"robust_kernel": "none"}},
    "outlier_free": {"outliers": 0.0, "params": {}},
}


def _gt_at(times_ns: NDArray[np.int64], gt_t: NDArray[np.int64], gt_T: F64) -> F64:
    return np.stack([interpolate_pose_at(int(x), gt_t, gt_T) for x in times_ns])


def posed_sequence_experiment(
    gt_times_ns: NDArray[np.int64],
    T_world_camera: F64,
    T_base_camera: F64,
    params: FusionParams | None = None,
    seeds: int = 5,
    odom_rate_hz: float = 100.0,
    vloc_rate_hz: float = 1.0,
    drift: DriftParams | None = None,
    progress: Callable[[], None] | None = None,
    tum_dir: Path | None = None,
) -> dict[str, Any]:
    """Run every variant for `seeds` seeds; returns a JSON-ready dict (see module doc).

    With `tum_dir`, seed 0's trajectories (base_link) are written there as TUM files:
    ground_truth, odometry, vloc, fused_<variant>, batch_<variant> (times in seconds).
    """
    p0 = params or FusionParams()
    drift = drift or DriftParams()
    gt_t = np.asarray(gt_times_ns, dtype=np.int64)
    T_wb = np.asarray(T_world_camera) @ invert(T_base_camera)
    per: dict[str, list[float]] = {}
    rates: dict[str, list[float]] = {}
    timing: dict[str, list[float]] = {}

    def put(d: dict[str, list[float]], k: str, v: float) -> None:
        d.setdefault(k, []).append(float(v))

    for s in range(seeds):
        ot, oT = simulate_odometry(gt_t, T_wb, odom_rate_hz, drift, seed=s)
        gt_o = _gt_at(ot, gt_t, T_wb)
        dur = (ot[-1] - ot[0]) * 1e-9
        put(per, "odometry", ate(oT, gt_o).rmse)
        put(rates, "odometry", (len(ot) - 1) / dur)
        for name, v in VARIANTS.items():
            p = dataclasses.replace(p0, **v["params"])
            vl = simulate_vloc(gt_t, T_world_camera, vloc_rate_hz, p0.vloc_sigma_trans, p0.vloc_sigma_rot_deg,
                               v["outliers"], seed=1000 + s)
            if name in ("robust", "outlier_free"):
                T_vb = vl.T_map_camera @ invert(T_base_camera)
                put(per, f"vloc_{name}", ate(T_vb, _gt_at(vl.t_capture_ns, gt_t, T_wb)).rmse)
                put(rates, f"vloc_{name}", len(vl.t_capture_ns) / dur)
            run = run_online(p, T_base_camera, ot, oT, vl)
            m = run.initialised
            put(per, f"fused_{name}", ate(run.T_map_base[m], gt_o[m]).rmse)
            put(per, f"fused_{name}_unaligned", ate(run.T_map_base[m], gt_o[m], align=False).rmse)
            put(rates, f"fused_{name}", (m.sum() - 1) / max((ot[m][-1] - ot[m][0]) * 1e-9, 1e-9))
            for q in (50, 99):
                put(timing, f"fused_{name}_odometry_call_ms_p{q}", np.percentile(run.odometry_call_ms, q))
            put(timing, f"fused_{name}_odometry_cpu_ms_p99", np.percentile(run.odometry_cpu_ms, 99))
            put(timing, f"fused_{name}_init_delay_s", (ot[m][0] - ot[0]) * 1e-9)
            t0 = time.perf_counter()
            b = refine_session(ot, oT, vl.t_capture_ns, vl.T_map_camera, None, p, T_base_camera)
            if tum_dir is not None and s == 0:
                if name == "robust":  # the inputs once
                    write_tum(tum_dir / "ground_truth.txt", gt_t * 1e-9, T_wb)
                    write_tum(tum_dir / "odometry.txt", ot * 1e-9, oT)
                    write_tum(tum_dir / "vloc.txt", vl.t_capture_ns * 1e-9, vl.T_map_camera @ invert(T_base_camera))
                write_tum(tum_dir / f"fused_{name}.txt", ot[m] * 1e-9, run.T_map_base[m])
                write_tum(tum_dir / f"batch_{name}.txt", b.times_ns * 1e-9, b.T_map_base)
            put(timing, f"batch_{name}_seconds", time.perf_counter() - t0)
            put(per, f"batch_{name}", ate(b.T_map_base, gt_o).rmse)
            put(rates, f"batch_{name}", (len(b.times_ns) - 1) / dur)
            if progress is not None:
                progress()
    med = {k: float(np.median(v)) for k, v in per.items()}
    rows = {
        "odometry": med["odometry"],
        "vloc": med["vloc_robust"],
        "fused": med["fused_robust"],
        "batch": med["batch_robust"],
    }
    return {
        "ate_m": rows,
        "rate_hz": {
            "odometry": float(np.median(rates["odometry"])),
            "vloc": float(np.median(rates["vloc_robust"])),
            "fused": float(np.median(rates["fused_robust"])),
            "batch": float(np.median(rates["batch_robust"])),
        },
        "ate_m_all": med,
        "ate_m_per_seed": per,
        "timing": {k: float(np.median(v)) for k, v in timing.items()},
        "seeds": seeds,
        "duration_s": float((gt_t[-1] - gt_t[0]) * 1e-9),
        "fusion_params": dataclasses.asdict(p0),
        "drift_params": dataclasses.asdict(drift),
        "inputs": {
            "odometry": f"simulate_odometry(rate {odom_rate_hz:g} Hz, DriftParams(), seed=s),"
            f" s in 0..{seeds - 1}",
            "vloc": f"simulate_vloc({vloc_rate_hz:g} Hz, sigma {p0.vloc_sigma_trans} m /"
            f" {p0.vloc_sigma_rot_deg} deg, 10 % outliers 0.5-3 m / 10-60 deg,"
            " latency U(0.1, 1.0) s, seed=1000+s)",
            "ate": "translation RMSE after SE(3) Umeyama alignment (no scale); median over seeds",
        },
    }


def long_run_experiment(
    minutes: float = 30.0,
    params: FusionParams | None = None,
    seed: int = 0,
    blocks: int = 6,
    progress: Callable[[int], object] | None = None,
) -> dict[str, Any]:
    """Synthetic endurance run: 100 Hz odometry + 1 Hz VLoc (10 % outliers) for `minutes`.

    Reports per block (of `blocks` equal time blocks): p50/p99/max of `add_odometry` and
    `add_vloc` call times, states in the graph; RSS (MiB) at the start and the end.
    """
    p = params or FusionParams()
    from litevloc.base.params.drift import T_BASE_CAMERA_OPTICAL

    gt_t, T_wb = synthetic_trajectory(minutes * 60.0, 30.0, seed=seed)
    ot, oT = simulate_odometry(gt_t, T_wb, 100.0, DriftParams(), seed=seed)
    vl = simulate_vloc(
        gt_t,
        T_wb @ T_BASE_CAMERA_OPTICAL,
        1.0,
        p.vloc_sigma_trans,
        p.vloc_sigma_rot_deg,
        0.1,
        seed=1000 + seed,
    )
    n = len(ot)
    edges = np.linspace(0, n, blocks + 1).astype(int)
    states = np.zeros(n, dtype=np.int32)
    rss: dict[str, float] = {}
    step = max(n // 100, 1)

    def probe(i: int, fusion: object) -> None:
        if i == 1000:  # after warm-up (first allocations, GTSAM caches)
            rss["start"] = memory_mb()["rss"]
        if i % 100 == 0:
            states[i] = fusion.states_in_graph()  # type: ignore[attr-defined]
        if progress is not None and i % step == 0:
            progress(step)

    load = os.getloadavg()
    run = run_online(p, T_BASE_CAMERA_OPTICAL, ot, oT, vl, on_sample=probe)
    rss["end"] = memory_mb()["rss"]
    varr = vl.t_arrival_ns[np.argsort(vl.t_arrival_ns, kind="stable")]
    vblock = np.searchsorted(ot, varr[: len(run.vloc_call_ms)])
    out_blocks = []
    for b in range(blocks):
        a, z = edges[b], edges[b + 1]
        om = run.odometry_call_ms[a:z]
        oc = run.odometry_cpu_ms[a:z]
        vsel = (vblock >= a) & (vblock < z)
        vm = run.vloc_call_ms[vsel]
        vc = run.vloc_cpu_ms[vsel]
        st = states[a:z:100]
        out_blocks.append(
            {
                "minutes": [
                    float((ot[a] - ot[0]) * 1e-9 / 60),
                    float((ot[z - 1] - ot[0]) * 1e-9 / 60),
                ],
                "odometry_call_ms_p50": float(np.percentile(om, 50)),
                "odometry_call_ms_p99": float(np.percentile(om, 99)),
                "odometry_call_ms_max": float(om.max()),
                "odometry_cpu_ms_p99": float(np.percentile(oc, 99)),
                "vloc_cpu_ms_p99": float(np.percentile(vc, 99)) if len(vc) else None,
                "vloc_call_ms_p50": float(np.percentile(vm, 50)) if len(vm) else None,
                "vloc_call_ms_p99": float(np.percentile(vm, 99)) if len(vm) else None,
                "states_max": int(st.max()),
            }
        )
    m = run.initialised
    gt_o = _gt_at(ot[m][::10], gt_t, T_wb)
    return {
        "minutes": minutes,
        "odometry_messages": int(n),
        "fused_outputs": int(m.sum()),
        "vloc_results": len(vl.t_capture_ns),
        "blocks": out_blocks,
        "odometry_call_ms_p99": float(np.percentile(run.odometry_call_ms, 99)),
        "vloc_call_ms_p99": float(np.percentile(run.vloc_call_ms, 99)),
        "all_calls_ms_p99": float(
            np.percentile(np.concatenate([run.odometry_call_ms, run.vloc_call_ms]), 99)
        ),
        "all_calls_cpu_ms_p99": float(
            np.percentile(np.concatenate([run.odometry_cpu_ms, run.vloc_cpu_ms]), 99)
        ),
        "smoother_update_ms_p99": run.stats["update_ms_p99"],
        "load_average_1min": [load[0], os.getloadavg()[0]],
        "states_in_graph_max": int(states.max()),
        "rss_mib_start": rss.get("start"),
        "rss_mib_end": rss["end"],
        "fused_ate_m": ate(run.T_map_base[m][::10], gt_o).rmse,
        "odometry_ate_m": ate(oT[m][::10], gt_o).rmse,
        "stats": run.stats,
    }


def table(res: dict[str, Any]) -> str:
    """ATE and rate per method, as printed by `litevloc bench fusion`."""
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


def long_table(lr: dict[str, Any]) -> str:
    """The synthetic endurance run's call times per block."""
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


def run_benchmark(
    src_path: Path, frames: slice, cfg: LiteVLocConfig, seeds: int, synthetic_minutes: float = 0.0,
    tum_dir: Path | None = None, on_run: Callable[[], None] | None = None,
    on_message: Callable[[int], object] | None = None,
) -> dict[str, Any]:
    """`litevloc bench fusion` / `bench/fusion.py`: `posed_sequence_experiment` on a posed dataset
    (its ground truth, the config's camera mount, fusion and drift settings) and, with
    `synthetic_minutes`, `long_run_experiment`. ValueError when the input has too few poses."""
    from litevloc.runtime.sources import open_source

    src = open_source(src_path, frames, rgbd_calibration=cfg.rgbd_calibration)
    ground_truth = getattr(src, "ground_truth", None)
    if ground_truth is None:
        raise ValueError(f"{src_path}: needs ground-truth poses (a posed dataset folder)")
    gt_t, T_wc = ground_truth()
    if len(gt_t) < 10:
        raise ValueError(f"{src_path}: only {len(gt_t)} ground-truth poses in the frames given (need >= 10)")
    params = cfg.fusion.params
    res = posed_sequence_experiment(gt_t, T_wc, cfg.fusion.T_base_camera(), params, seeds=seeds,
                                    drift=cfg.odometry_sim.drift, progress=on_run, tum_dir=tum_dir)
    res["source"] = src.name
    if synthetic_minutes > 0:
        res["synthetic"] = long_run_experiment(synthetic_minutes, params, progress=on_message)
    res["fusion_params"] = dataclasses.asdict(params)
    return res


def report(res: dict[str, Any], seeds: int) -> str:
    """The printed summary of `run_benchmark`."""
    t = res["timing"]
    lines = [f"fusion on {res['source']} frames {res.get('frames', '')} ({res['duration_s']:.1f} s), median of "
             f"{seeds} seeds", table(res),
             f"online add_odometry p50/p99: {t['fused_robust_odometry_call_ms_p50']:.3f}/"
             f"{t['fused_robust_odometry_call_ms_p99']:.3f} ms "
             f"(cpu p99 {t['fused_robust_odometry_cpu_ms_p99']:.3f} ms); batch solve {t['batch_robust_seconds']:.2f} s"]
    if "synthetic" in res:
        lines.append(long_table(res["synthetic"]))
    return "\n".join(lines)
