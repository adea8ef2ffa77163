"""Matcher benchmark: full-depth LightGlue vs its int8 and adaptive (early stopping + point
pruning) forms, and top-N keypoint caps, on the pairs localization really matches.

Pairs (7-Scenes redkitchen, the fixed protocol): each query frame of 500-999 (every `--step`)
with the mapping-pass frame (0-499) nearest to it in pose (position + 0.5 m per radian of
viewing-direction difference) -- the pair an LL query matches against its best keyframe.
Features: ALIKED-n16 240x320 top-512 (the default extractor).

Per variant, with onnxruntime on 1 intra-op thread (as the runtime's VLoc stage), variants
interleaved pair by pair so machine load hits all alike:
- wall and thread-CPU time per pair (median, p90) and the ratio of medians to full LightGlue;
  the CPU time is what the variant costs, the wall time what it took on this (shared) machine;
- matches per pair and the median epipolar error (px, 640x480) against ground truth;
- for adaptive: layers run (of 9) and fraction of points left after pruning.

Usage: python bench/matcher.py [--step 10] [--json out/bench/matcher.json]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from litevloc.base.params.models import ModelsConfig
from litevloc.models.registry import default_cache_dir, load_extractor
from litevloc.runtime.vloc_models import ModelBundle, load_bundle

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data" / "7scenes-redkitchen"
K585 = np.array([[585.0, 0, 320], [0, 585.0, 240], [0, 0, 1]])

VARIANTS: dict[str, dict[str, Any]] = {
    "lightglue": {"matcher": "lightglue"},
    "lightglue-int8": {"matcher": "lightglue-int8"},
    "lightglue-adaptive": {"matcher": "lightglue-adaptive"},
    "lightglue @384": {"matcher": "lightglue", "match_max_keypoints": 384},
    "lightglue-adaptive @384": {"matcher": "lightglue-adaptive", "match_max_keypoints": 384},
}


def _rgb(i: int) -> np.ndarray:
    return cv2.cvtColor(cv2.imread(str(DATA / f"frame-{i:06d}.color.jpg")), cv2.COLOR_BGR2RGB)


def _pose(i: int) -> np.ndarray:
    return np.loadtxt(DATA / f"frame-{i:06d}.pose.txt")


def pairs(step: int) -> list[tuple[int, int]]:
    """(query, nearest mapping frame) per query frame."""
    mp = np.array([_pose(i) for i in range(500)])
    out = []
    for q in range(500, 1000, step):
        T = _pose(q)
        dpos = np.linalg.norm(mp[:, :3, 3] - T[:3, 3], axis=1)
        ang = np.arccos(np.clip(mp[:, :3, 2] @ T[:3, 2], -1, 1))
        out.append((q, int(np.argmin(dpos + 0.5 * ang))))
    return out


def epipolar_px(kp0: np.ndarray, kp1: np.ndarray, T_w_0: np.ndarray, T_w_1: np.ndarray) -> np.ndarray:
    """Distances (px) of kp1 to the epipolar lines of kp0 (both (N, 2) in 640x480 pixels)."""
    T = np.linalg.inv(T_w_1) @ T_w_0
    R, t = T[:3, :3], T[:3, 3]
    tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    Ki = np.linalg.inv(K585)
    F = Ki.T @ tx @ R @ Ki
    p0 = np.c_[kp0, np.ones(len(kp0))]
    p1 = np.c_[kp1, np.ones(len(kp1))]
    lines = p0 @ F.T
    return np.abs((lines * p1).sum(1)) / np.maximum(np.linalg.norm(lines[:, :2], axis=1), 1e-12)


def _stats(v: list[float]) -> dict[str, float]:
    a = np.asarray(v, float)
    return {"median": float(np.median(a)), "p90": float(np.percentile(a, 90))} if len(a) else {}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--step", type=int, default=10, help="every STEP-th query frame of 500-999")
    ap.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    ap.add_argument("--json", type=Path, default=ROOT / "out" / "bench" / "matcher.json")
    args = ap.parse_args()
    if not DATA.is_dir():
        raise SystemExit(f"7-Scenes data not found at {DATA}")
    # the variants without "@N" match all keypoints (the default caps at 384)
    base = ModelsConfig(cache_dir=str(default_cache_dir()), intra_op_threads=1, match_max_keypoints=0)
    from dataclasses import replace

    bundles: dict[str, ModelBundle] = {
        name: load_bundle(replace(base, **kw)) for name, kw in VARIANTS.items() if name in args.variants
    }
    ex = load_extractor("aliked-n16", base)
    prs = pairs(args.step)
    rec: dict[str, dict[str, list[float]]] = {n: {"wall": [], "cpu": [], "matches": [], "epi": []} for n in bundles}
    print(f"{len(prs)} pairs (query, nearest mapping frame), ALIKED-n16 240x320 top-512, ORT 1 thread", flush=True)
    for k, (q, m) in enumerate(prs):
        fq, fm = ex.extract(_rgb(q)), ex.extract(_rgb(m))
        Tq, Tm = _pose(q), _pose(m)
        for name, b in bundles.items():
            if k == 0:
                b.match(fq, fm)  # warm-up
            t0, c0 = time.perf_counter(), time.thread_time()
            i0, i1 = b.match(fq, fm)
            c1, t1 = time.thread_time(), time.perf_counter()
            r = rec[name]
            r["wall"].append(1e3 * (t1 - t0))
            r["cpu"].append(1e3 * (c1 - c0))
            r["matches"].append(len(i0))
            if len(i0):
                r["epi"].append(float(np.median(epipolar_px(fq.keypoints[i0], fm.keypoints[i1], Tq, Tm))))
        if (k + 1) % 10 == 0:
            print(f"  {k + 1}/{len(prs)} pairs", flush=True)
    ref = rec.get("lightglue")
    rows = []
    for name, r in rec.items():
        row: dict[str, Any] = {
            "variant": name, "wall_ms": _stats(r["wall"]), "cpu_ms": _stats(r["cpu"]),
            "matches": _stats(r["matches"]), "epipolar_px_median": float(np.median(r["epi"])) if r["epi"] else None,
            "pairs_with_50_matches": float(np.mean(np.asarray(r["matches"]) >= 50)),
        }
        if ref is not None:
            row["cpu_speedup_vs_full"] = float(np.median(ref["cpu"]) / np.median(r["cpu"]))
            row["wall_speedup_vs_full"] = float(np.median(ref["wall"]) / np.median(r["wall"]))
        matcher = getattr(bundles[name].matcher, "stats", None)
        if matcher is not None:
            row["layers_run"] = _stats(list(matcher.layers_run))
            row["points_kept"] = _stats(list(matcher.points_kept))
        rows.append(row)
    print(f"\n{'variant':<26}{'cpu ms med/p90':>16}{'wall ms med':>12}{'x full(cpu)':>12}{'matches':>9}"
          f"{'epi px':>8}{'layers':>8}{'kept':>6}")
    for row in rows:
        print(f"{row['variant']:<26}{row['cpu_ms']['median']:>8.0f}/{row['cpu_ms']['p90']:<7.0f}"
              f"{row['wall_ms']['median']:>12.0f}{row.get('cpu_speedup_vs_full', float('nan')):>12.2f}"
              f"{row['matches']['median']:>9.0f}{row['epipolar_px_median'] or float('nan'):>8.2f}"
              f"{row.get('layers_run', {}).get('median', float('nan')):>8.1f}"
              f"{row.get('points_kept', {}).get('median', float('nan')):>6.2f}")
    out = {"pairs": len(prs), "step": args.step, "load_avg": os.getloadavg(), "cpu": platform.processor(),
           "rows": rows}
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(out, indent=2) + "\n")
    print(f"\nwrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
