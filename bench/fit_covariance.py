"""Fit the covariance's systematic terms (`localization.refine.sigma_sys_*`) by maximum likelihood.

Reads `bench/accuracy.py` JSONs of the tuning splits (default: the two mapping-pass splits,
out/bench/dist_A.json and dist_B.json, written by

    python bench/accuracy.py --configs joint --map out/maps/7s-splitA --frames 0:250:2 --name dist_A
    python bench/accuracy.py --configs joint --map out/maps/7s-splitB --frames 250:500:2 --name dist_B

), takes every accepted pose's covariance apart into the solve's part (the recorded covariance
minus the systematic terms of the parameters it was made with) and its view angle and distance
to its keyframes, and fits, per block (position, rotation), the model of
`pipelines.localization.refine`:

    sigma^2 = a^2 + (b theta)^2 + (c d)^2

by maximising the Gaussian likelihood of the camera-frame errors (Nelder-Mead on log a, b, c).
Prints the fit, the share of errors inside their 95 % ellipsoid at scales 1.0-1.4 of the fitted
sigmas on the tuning splits and, with `--held-out JSON`, on another run (report only: a scale is
chosen on the splits). Writes out/bench/fit_covariance.json.

    python bench/fit_covariance.py [--tune A.json B.json] [--held-out out/bench/accuracy.json]
        [--model angle|distance|both]

The recorded covariance is the total after the floors (`min_sigma_*`); where a floor bound, the
solve's part recovered here is a little too large (the printed count says how often).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

import numpy as np
from _common import OUT, print_table, write_json
from numpy.typing import NDArray
from scipy.optimize import minimize
from scipy.stats import chi2

Q95 = float(chi2.ppf(0.95, 3))
MODELS = {"angle": (1, 1, 0), "distance": (1, 0, 1), "both": (1, 1, 1)}
Row = tuple[NDArray[np.float64], NDArray[np.float64], float, float, NDArray[np.float64], NDArray[np.float64]]


def load_rows(path: Path) -> tuple[list[Row], int]:
    """(solve covariance t 3x3, r 3x3, theta rad, distance m, error t, error rotvec) per accepted
    pose, and how many had a floor binding."""
    from litevloc.config import load_config
    from litevloc.pipelines.localization.refine import systematic_variances

    data = json.loads(path.read_text())
    res = data["results"][0]
    # the parameters the run had: its preset, the configuration's overrides, then the run's --set
    p = load_config(data.get("preset", "7scenes"),
                    list(res.get("overrides", [])) + list(data.get("overrides", []))).localization.refine
    rows: list[Row] = []
    floored = 0
    for f in res["frames"]:
        if not (f.get("accepted") and "covariance" in f and "keyframe_distance_m" in f):
            continue
        C = np.asarray(f["covariance"], np.float64)
        th, d = np.radians(f["view_angle_deg"]), float(f["keyframe_distance_m"])
        vt, vr = systematic_variances(p, th, d)
        floor = np.array([p.min_sigma_t_m] * 3 + [np.radians(p.min_sigma_r_deg)] * 3) ** 2
        floored += int(np.any(np.isclose(np.diag(C), floor, rtol=1e-9)))
        Cp = C.copy()
        Cp[np.diag_indices(6)] = np.maximum(np.diag(C) - np.array([vt] * 3 + [vr] * 3), 1e-14)
        rows.append((Cp[:3, :3], Cp[3:, 3:], float(th), d, np.asarray(f["err_cam_m"]),
                     np.asarray(f["err_cam_rotvec"])))
    return rows, floored


def _var(x: NDArray[np.float64], th: float, d: float) -> float:
    return float(x[0] ** 2 + (x[1] * th) ** 2 + (x[2] * d) ** 2)


def neg_log_likelihood(x: NDArray[np.float64], rows: list[Row], block: int) -> float:
    s = 0.0
    for r in rows:
        C = r[block] + np.eye(3) * _var(x, r[2], r[3])
        e = r[4 + block]
        s += 0.5 * float(e @ np.linalg.solve(C, e) + np.linalg.slogdet(C)[1])
    return s


def coverage_pct(x: NDArray[np.float64], rows: list[Row], block: int) -> float:
    inside = [float(r[4 + block] @ np.linalg.solve(r[block] + np.eye(3) * _var(x, r[2], r[3]), r[4 + block])) <= Q95
              for r in rows]
    return 100.0 * float(np.mean(inside)) if inside else float("nan")


def fit(rows: list[Row], block: int, use: tuple[int, int, int]) -> tuple[NDArray[np.float64], float]:
    """(a, b, c) of one block (position 0, rotation 1) and the minimised negative log-likelihood."""
    mask = np.asarray(use, np.float64)
    x0 = np.array([0.01, 0.1, 0.03]) if block == 0 else np.array([np.radians(0.5), 0.05, np.radians(1.0)])
    res = minimize(lambda lx: neg_log_likelihood(np.exp(lx) * mask, rows, block), np.log(x0), method="Nelder-Mead",
                   options={"maxiter": 4000, "xatol": 1e-6, "fatol": 1e-6})
    return np.exp(res.x) * mask, float(res.fun)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--tune", nargs="+", type=Path, default=[OUT / "dist_A.json", OUT / "dist_B.json"])
    ap.add_argument("--held-out", type=Path, default=None)
    ap.add_argument("--model", choices=sorted(MODELS), default="both")
    args = ap.parse_args()
    for p in [*args.tune, *([args.held_out] if args.held_out else [])]:
        if not p.is_file():
            raise SystemExit(f"{p} not found: run bench/accuracy.py first (see this script's docstring)")
    tune: list[Row] = []
    for p in args.tune:
        r, n_floor = load_rows(p)
        print(f"{p.name}: {len(r)} accepted poses ({n_floor} with a floor binding)")
        tune += r
    held = load_rows(args.held_out)[0] if args.held_out else []
    out: dict[str, Any] = {"model": args.model, "tune": [str(p) for p in args.tune], "n_tune": len(tune),
                           "held_out": str(args.held_out) if args.held_out else None, "blocks": {}}
    rows = []
    deg = float(np.degrees(1.0))
    for block, name, unit in ((0, "position", (1.0, 1.0, 1.0)), (1, "rotation", (deg, 1.0, deg))):
        x, nll = {}, {}
        for m, use in MODELS.items():
            x[m], nll[m] = fit(tune, block, use)
        xb = x[args.model]
        cov = {k: (coverage_pct(xb * k, tune, block), coverage_pct(xb * k, held, block) if held else None)
               for k in (1.0, 1.1, 1.2, 1.3, 1.4)}
        out["blocks"][name] = {"a_b_c": (xb * np.asarray(unit)).tolist(), "neg_log_likelihood": nll,
                               "coverage_pct_by_scale": {str(k): v for k, v in cov.items()}}
        for k, (ct, ch) in cov.items():
            rows.append([name, f"{xb[0] * unit[0]:.4g}", f"{xb[1]:.4g}", f"{xb[2] * unit[2]:.4g}", k,
                         round(ct, 1), "" if ch is None else round(ch, 1)])
        print(f"{name}: -log L angle {nll['angle']:.1f}, distance {nll['distance']:.1f}, both {nll['both']:.1f}")
    print_table(f"systematic covariance terms, model '{args.model}' (position: m, m/rad, m/m; rotation: deg, rad/rad, "
                "deg/m), share inside the 95 % ellipsoid at each scale",
                ["block", "a", "b (per rad)", "c (per m)", "scale", "tuning %", "held-out %"], rows)
    write_json("fit_covariance", out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
