"""Is fusion's covariance an honest prior gate? The error of a fused prior against its covariance.

LL accepts a pose only inside the prior gate; toward a pose, the gate of a fused prior is at
most `prior_gate.fused_m` + `prior_gate.sigmas` sigma of the fused camera position along the
offset (`pipelines.localization.prior_gate`, as LL uses it). That is only safe if fusion's covariance covers the
odometry's real drift. Here, on a simulator pass (its own drift model, with a yaw bias the
fusion model does not have): every `--every` s, fusion (the runtime's `OnlineFusion`, default
settings) starts on two fixes at the truth (0.5 s apart, 1 cm / 0.5 deg), then gets odometry
alone for `age` s; at the end the fused camera position's error is compared with its covariance.

Reported per pass and age: the error (median, max), error / sigma along the error (median,
max), the gate toward the truth and along the optical axis (where a repeated texture puts the
wrong copy), and how many windows would refuse the true pose (`right refused`: error over the
gate toward it; the age gate `prior_gate.fused_m` + `prior_gate.rate_fused_mps` x age beside it).

    python bench/prior_gate.py [--passes sim:loop?pass=loop-lane&seed=0 ...] [--ages 2 6 15 30]
"""

from __future__ import annotations

import argparse
from typing import Any

import numpy as np
from _common import print_table, write_json

from litevloc.base.geometry import camera_position_covariance
from litevloc.config import load_config
from litevloc.pipelines.fusion.online import OnlineFusion
from litevloc.pipelines.localization.prior import narrowed_gate, sigma_along
from litevloc.sim.source import open_sim_source

_FIX_COV = np.diag([0.01**2] * 3 + [np.radians(0.5) ** 2] * 3)  # ROS order: a well-verified VLoc fix


def window(cfg: Any, run: Any, T_bc: np.ndarray, s_ns: int, age_s: float) -> dict[str, float] | None:
    """Fusion from two fixes at the truth (at s - 0.5 s and s), then `age_s` of odometry alone:
    the camera position's error (m) and its sigma along the error and along the optical axis (m)."""
    t, T_world, T_odom = run.t_ns, run.T_world_base, run.T_odom_base
    k0, kv = (int(np.searchsorted(t, s_ns - d)) for d in (2_000_000_000, 500_000_000))
    ks, ke = int(np.searchsorted(t, s_ns)), int(np.searchsorted(t, s_ns + int(age_s * 1e9)))
    if ke >= len(t):
        return None
    fusion = OnlineFusion(cfg.fusion.params, T_bc)
    for k in range(k0, ks + 1):
        fusion.add_odometry(int(t[k]), T_odom[k])
        if k in (kv, ks):
            fusion.add_vloc(int(t[k]), T_world[k] @ T_bc, _FIX_COV)
    out = None
    for k in range(ks + 1, ke + 1):
        out = fusion.add_odometry(int(t[k]), T_odom[k])
    if out is None:
        return None
    T_true = T_world[ke] @ T_bc
    e = (np.asarray(out.T_map_base) @ T_bc)[:3, 3] - T_true[:3, 3]
    C = camera_position_covariance(out.T_map_base, out.covariance, T_bc)
    return {"err_m": float(np.linalg.norm(e)), "sigma_err_m": sigma_along(C, e),
            "sigma_axis_m": sigma_along(C, T_true[:3, 2])}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--passes", nargs="+", default=["sim:loop?pass=loop-lane&seed=0", "sim:office?pass=query&seed=0"])
    ap.add_argument("--ages", nargs="+", type=float, default=[2.0, 6.0, 15.0, 30.0], help="seconds of odometry alone")
    ap.add_argument("--every", type=float, default=2.0, help="window start spacing (s)")
    ap.add_argument("--json", default="prior_gate")
    a = ap.parse_args()
    cfg = load_config("default", [])
    lp, T_bc = cfg.localization, cfg.fusion.T_base_camera()
    rows, results = [], []
    for uri in a.passes:
        run = open_sim_source(uri, params=cfg.sim).run
        for age in a.ages:
            starts = np.arange(4.0, run.t_ns[-1] * 1e-9 - age, a.every)
            ws = [w for s in starts if (w := window(cfg, run, T_bc, int(s * 1e9), age)) is not None]
            if not ws:
                continue
            err = np.array([w["err_m"] for w in ws])
            z = err / np.array([w["sigma_err_m"] for w in ws])
            age_gate = lp.prior_gate.fused_m + lp.prior_gate.rate_fused_mps * age
            gate_err, gate_axis = (np.array([narrowed_gate(age_gate, lp.prior_gate.fused_m, lp.prior_gate.sigmas,
                                                           w[key]) for w in ws])
                                   for key in ("sigma_err_m", "sigma_axis_m"))
            r = {"pass": uri, "age_s": age, "windows": len(ws), "err_median_m": float(np.median(err)),
                 "err_max_m": float(err.max()), "z_median": float(np.median(z)), "z_max": float(z.max()),
                 "gate_axis_median_m": float(np.median(gate_axis)), "gate_axis_max_m": float(gate_axis.max()),
                 "age_gate_m": age_gate, "right_refused": int((err > gate_err).sum()),
                 "right_refused_age_gate": int((err > age_gate).sum())}
            results.append(r)
            rows.append([uri.removeprefix("sim:"), f"{age:g}", len(ws),
                         f"{r['err_median_m']:.3f} / {r['err_max_m']:.3f}",
                         f"{r['z_median']:.2f} / {r['z_max']:.2f}", f"{r['gate_axis_median_m']:.2f} / "
                         f"{r['gate_axis_max_m']:.2f}", f"{age_gate:.2f}", f"{r['right_refused']} / "
                         f"{r['right_refused_age_gate']}"])
            print(f"{uri} age {age:g} s: {len(ws)} windows", flush=True)
    print_table(f"Fused prior vs its covariance (prior_gate_sigmas {lp.prior_gate.sigmas:g})",
                ["pass", "age s", "windows", "error m (median / max)", "error / sigma (median / max)",
                 "gate along axis m (median / max)", "age gate m", "right refused (cov / age gate)"], rows)
    write_json(a.json, {"prior_gate_sigmas": lp.prior_gate.sigmas, "results": results})


if __name__ == "__main__":
    main()
