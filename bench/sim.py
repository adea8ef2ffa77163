"""Simulator benchmark: render time per frame, recording throughput, ORB place matching.

    .venv/bin/python bench/sim.py [--quick]

Prints tables and writes out/bench/sim.json. Measured:

* render time (median over poses of a map pass) of the ideal renderer, and of a full
  frame (renderer + realism), at 320x240 and 640x480, for a small and a large world
  (ratio: full frame vs ideal render in the same run);
* closed-loop stepping (`Simulator.step` at 5 Hz, the navigation loop's rate) on the
  office, floor and loop worlds: wall time per simulated second when every step renders
  colour + depth (before) vs colour only on the 1 Hz VLoc steps and depth alone on the
  others (what `sim navigate` does now) vs depth only (the ground-truth baseline run);
  ratios against the every-step-colour pattern of the same run;
* time to simulate + render + record a 60 s, 15 Hz pass to MCAP (office);
* ORB place matching between map-pass and query-pass frames: verified PnP inliers
  (map keypoints lifted with the map frame's depth, RANSAC) for pairs of the same place
  (nearest map frame in position and heading) vs pairs from different rooms, and the
  pose error of the same-place PnP solutions against ground truth.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from litevloc.base.geometry import backproject_pixels, invert, relative_pose_error
from litevloc.base.params.sim import SimParams
from litevloc.sim.render import Renderer
from litevloc.sim.source import SimSequenceSource
from litevloc.sim.world import load_world


def _pct(x: Sequence[float] | np.ndarray) -> dict[str, float]:
    a = np.asarray(x, dtype=np.float64)
    if len(a) == 0:
        return {"n": 0}
    return {
        "n": len(a),
        "p10": float(np.percentile(a, 10)),
        "p50": float(np.median(a)),
        "p90": float(np.percentile(a, 90)),
        "mean": float(a.mean()),
    }


def bench_render(world_name: str, n: int) -> dict[str, dict[str, float]]:
    world = load_world(world_name)
    t0 = time.perf_counter()
    ren = Renderer(world)
    bake_s = time.perf_counter() - t0
    out: dict[str, dict[str, float]] = {"bake_s": {"value": bake_s}}
    for w, h in ((320, 240), (640, 480)):
        params = SimParams(width=w, height=h)
        src = SimSequenceSource(world, "map", 0, duration=60.0, params=params)
        idx = np.linspace(0, src.frame_count() - 1, n).astype(int)
        poses = src.camera_poses()[idx]
        K = params.intrinsics
        ren.render(poses[0], K)
        ideal, full = [], []
        for i, T in zip(idx, poses, strict=True):
            t0 = time.perf_counter()
            ren.render(T, K)
            ideal.append(time.perf_counter() - t0)
            src._renderer = ren
            t0 = time.perf_counter()
            src.frame(int(i))
            full.append(time.perf_counter() - t0)
        mi, mf = float(np.median(ideal)) * 1e3, float(np.median(full)) * 1e3
        out[f"{w}x{h}"] = {
            "render_ms_p50": mi,
            "frame_ms_p50": mf,
            "frame_vs_render": mf / mi,
            "render_ms_p90": float(np.percentile(ideal, 90)) * 1e3,
        }
    return out


def bench_steps(world_name: str, sim_seconds: float) -> dict[str, float]:
    """Wall time per simulated second of `Simulator.step` at 5 Hz, three render patterns."""
    from litevloc.sim.simulator import Simulator

    world = load_world(world_name)
    start = world.goal_places[sorted(world.goal_places)[0]]
    n = int(sim_seconds * 5)
    out: dict[str, float] = {}
    for name, every in (("rgbd_every_step", 1), ("rgbd_at_vloc_1hz", 5), ("depth_only", 0)):
        sim = Simulator(world, SimParams(), seed=0)
        sim.reset(start)
        rng = np.random.default_rng(0)
        t0 = time.perf_counter()
        for k in range(1, n + 1):
            color = every > 0 and k % every == 0
            step = sim.step(0.3, float(rng.uniform(-0.5, 0.5)), 0.2, color=color)
            if step.collided:
                sim.reset(start, step.t_ns)
        out[f"{name}_wall_per_sim_s"] = (time.perf_counter() - t0) / sim_seconds
    base = out["rgbd_every_step_wall_per_sim_s"]
    out["speedup_vloc_pattern"] = base / out["rgbd_at_vloc_1hz_wall_per_sim_s"]
    out["speedup_depth_only"] = base / out["depth_only_wall_per_sim_s"]
    return out


def bench_map_feed(world_name: str, sim_seconds: float) -> dict[str, float]:
    """Rendering cost of feeding a mapping pass to the map builder, per frame of the pass:
    `sim record` renders colour + depth and JPEG-encodes every frame (then `map build`
    decodes them again); `map build sim:` renders depth only, and only for frames that
    pass the motion pre-filter (colour later for the keyframes alone, not counted here)."""
    from litevloc.config import load_config
    from litevloc.pipelines.topomap.build import MapBuilder

    cfg = load_config("default")
    src = SimSequenceSource(load_world(world_name), "map", 0, duration=sim_seconds, params=cfg.sim)
    n = src.frame_count()
    src.frame(0)  # bake textures outside the timing
    t0 = time.perf_counter()
    for i in range(n):
        f = src.frame(i)
        _ok, buf = cv2.imencode(".jpg", f.color[:, :, ::-1], [cv2.IMWRITE_JPEG_QUALITY, 90])
        cv2.imdecode(buf, cv2.IMREAD_COLOR)
    full = (time.perf_counter() - t0) / n
    t0 = time.perf_counter()
    for i in range(n):
        src.depth(i)
    depth_all = (time.perf_counter() - t0) / n
    b = MapBuilder(cfg.mapping, lambda im: None, lambda im: None, lambda a, b_: None, "x", "y")
    poses = src.camera_poses()
    K = cfg.sim.intrinsics.K
    t0 = time.perf_counter()
    for i, t in enumerate(src.frame_times):
        if b.is_candidate(poses[i]):
            b.add(int(t), None, src.depth(i), K, poses[i], i)
        else:
            b.add_pose(poses[i], i)
    cand = (time.perf_counter() - t0) / n
    return {"frames": n, "candidates": b.report.candidates, "rgbd_jpeg_ms_per_frame": full * 1e3,
            "depth_all_ms_per_frame": depth_all * 1e3, "depth_candidates_ms_per_frame": cand * 1e3,
            "speedup_depth_all": full / depth_all, "speedup_depth_candidates": full / cand}


def bench_record(seconds: float) -> dict[str, float]:
    from litevloc.config import load_config
    from litevloc.runtime.tools.sim_recording import record_pass

    with tempfile.TemporaryDirectory() as d:
        t0 = time.perf_counter()
        info = record_pass(load_world("office"), "map", 0, seconds, load_config(None).sim, Path(d) / "r.mcap")
        wall = time.perf_counter() - t0
    return {
        "simulated_s": info["simulated_seconds"],
        "frames": info["frames"],
        "wall_s": wall,
        "planning_s": info["planning_seconds"],
        "mb": info["bytes"] / 1e6,
        "realtime_factor": info["simulated_seconds"] / wall,
    }


def _fmt(d: dict[str, float], digits: int = 0) -> str:
    if not d.get("n"):
        return "n=0"
    return f"n={d['n']} " + "/".join(f"{d[k]:.{digits}f}" for k in ("p10", "p50", "p90"))


def bench_orb(world_name: str, n_query: int, seed: int = 0) -> dict[str, Any]:
    world = load_world(world_name)
    params = SimParams()
    K = params.intrinsics.K
    mp = SimSequenceSource(world, "map", seed, params=params)
    qp = SimSequenceSource(world, "query", seed, params=params)
    m_idx = np.arange(0, mp.frame_count(), 5)
    m_poses = mp.camera_poses()[m_idx]
    q_all = qp.camera_poses()
    q_idx = np.linspace(0, qp.frame_count() - 1, n_query).astype(int)
    orb = cv2.ORB_create(1000)  # type: ignore[attr-defined]
    bf = cv2.BFMatcher(cv2.NORM_HAMMING)
    cache: dict[int, tuple] = {}

    def feats(src: SimSequenceSource, i: int, key: int) -> tuple:
        if key not in cache:
            f = src.frame(i)
            kp, des = orb.detectAndCompute(cv2.cvtColor(f.color, cv2.COLOR_RGB2GRAY), None)
            cache[key] = (f, kp, des)
        return cache[key]

    def region(T: np.ndarray) -> int:
        return world.region_at(T[:2, 3])

    def pnp(q: tuple, m: tuple) -> tuple[int, np.ndarray | None]:
        (_, kq, dq), (fm, km, dm) = q, m
        if dq is None or dm is None or len(kq) < 8 or len(km) < 8:
            return 0, None
        good = [
            a
            for a, b in (p for p in bf.knnMatch(dq, dm, k=2) if len(p) == 2)
            if a.distance < 0.8 * b.distance
        ]
        if len(good) < 6:
            return 0, None
        uv_m = np.array([km[g.trainIdx].pt for g in good])
        uv_q = np.array([kq[g.queryIdx].pt for g in good])
        z = fm.depth[
            np.clip(uv_m[:, 1].round().astype(int), 0, fm.height - 1),
            np.clip(uv_m[:, 0].round().astype(int), 0, fm.width - 1),
        ]
        ok = np.isfinite(z)
        if ok.sum() < 6:
            return 0, None
        P = backproject_pixels(K, uv_m[ok], z[ok])
        res = cv2.solvePnPRansac(
            P,
            uv_q[ok],
            K,
            None,
            iterationsCount=200,
            reprojectionError=3.0,
            flags=cv2.SOLVEPNP_EPNP,
        )
        if not res[0] or res[3] is None:
            return 0, None
        R, _ = cv2.Rodrigues(res[1])
        T_q_m = np.eye(4)
        T_q_m[:3, :3], T_q_m[:3, 3] = R, res[2].ravel()
        return len(res[3]), T_q_m

    rng = np.random.default_rng(1)
    same, diff, t_err, r_err, dists = [], [], [], [], []
    for qi in q_idx:
        Tq = q_all[qi]
        d = np.linalg.norm(m_poses[:, :2, 3] - Tq[:2, 3], axis=1)
        ang = np.degrees(
            np.arccos(np.clip(np.einsum("ij,j->i", m_poses[:, :3, 2], Tq[:3, 2]), -1, 1))
        )
        score = d + ang / 30.0
        j = int(np.argmin(score))
        if d[j] > 1.0 or ang[j] > 30:
            continue
        q = feats(qp, int(qi), -1 - int(qi))
        n_in, T_q_m = pnp(q, feats(mp, int(m_idx[j]), int(m_idx[j])))
        same.append(n_in)
        dists.append(float(d[j]))
        if T_q_m is not None and n_in >= 12:
            T_est = m_poses[j] @ invert(T_q_m)
            te, re = relative_pose_error(T_est, Tq)
            t_err.append(te)
            r_err.append(re)
        others = np.nonzero(np.array([region(T) != region(Tq) for T in m_poses]))[0]
        if len(others):
            k = int(rng.choice(others))
            diff.append(pnp(q, feats(mp, int(m_idx[k]), int(m_idx[k])))[0])
    thr = 12
    return {
        "world": world_name,
        "pairs_same": len(same),
        "pairs_diff": len(diff),
        "same_place_inliers": _pct(same),
        "different_room_inliers": _pct(diff),
        "same_frac_ge_thr": float(np.mean(np.array(same) >= thr)) if same else 0.0,
        "diff_frac_ge_thr": float(np.mean(np.array(diff) >= thr)) if diff else 0.0,
        "inlier_threshold": thr,
        "same_pose_err_m": _pct(t_err),
        "same_pose_err_deg": _pct(r_err),
        "same_pair_distance_m": _pct(dists),
    }


def main() -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--quick", action="store_true", help="fewer samples")
    ap.add_argument("--steps-only", action="store_true", help="only the closed-loop stepping table")
    ap.add_argument("--json", type=Path, default=Path("out/bench/sim.json"))
    args = ap.parse_args()
    n = 10 if args.quick else 30
    results: dict[str, Any] = {}
    print("== closed-loop stepping at 5 Hz, wall s per simulated s (same run) ==")
    for wn in ("office", "floor", "loop"):
        st = bench_steps(wn, 10.0 if args.quick else 30.0)
        results[f"steps_{wn}"] = st
        print(
            f"  {wn:7s} colour every step {st['rgbd_every_step_wall_per_sim_s']:.3f}; colour at 1 Hz "
            f"{st['rgbd_at_vloc_1hz_wall_per_sim_s']:.3f} (x{st['speedup_vloc_pattern']:.2f}); depth only "
            f"{st['depth_only_wall_per_sim_s']:.3f} (x{st['speedup_depth_only']:.2f})"
        )
    print("== mapping-pass feed, ms per frame of the pass (same run) ==")
    for wn in ("floor",):
        mf = bench_map_feed(wn, 10.0 if args.quick else 30.0)
        results[f"map_feed_{wn}"] = mf
        print(
            f"  {wn:7s} {mf['frames']} frames ({mf['candidates']} candidates): colour+depth+JPEG "
            f"{mf['rgbd_jpeg_ms_per_frame']:.1f}; depth only {mf['depth_all_ms_per_frame']:.1f} "
            f"(x{mf['speedup_depth_all']:.2f}); depth for candidates only (builder pass 1 incl.) "
            f"{mf['depth_candidates_ms_per_frame']:.1f} (x{mf['speedup_depth_candidates']:.2f})"
        )
    if args.steps_only:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(results, indent=2, sort_keys=True) + "\n")
        print(f"wrote {args.json}")
        return 0
    print("== render time per frame (one core, median ms) ==")
    for wn in ("office", "loop"):
        r = bench_render(wn, n)
        results[f"render_{wn}"] = r
        print(f"{wn:8s} bake {r['bake_s']['value']:.2f} s")
        for size in ("320x240", "640x480"):
            v = r[size]
            print(
                f"  {size}: render p50 {v['render_ms_p50']:.1f} ms (p90 {v['render_ms_p90']:.1f}), "
                f"full frame p50 {v['frame_ms_p50']:.1f} ms (x{v['frame_vs_render']:.2f} of render)"
            )
    print("== record a pass to MCAP (office) ==")
    rec = bench_record(20.0 if args.quick else 60.0)
    results["record_office"] = rec
    print(
        f"  {rec['simulated_s']:.0f} s simulated, {rec['frames']} frames, {rec['mb']:.1f} MB "
        f"in {rec['wall_s']:.1f} s (x{rec['realtime_factor']:.2f} real time, "
        f"planning {rec['planning_s']:.1f} s)"
    )
    print("== ORB + PnP place matching, map pass vs query pass (verified inliers p10/p50/p90) ==")
    for wn in ("office", "floor"):
        o = bench_orb(wn, 25 if args.quick else 80)
        results[f"orb_{wn}"] = o
        print(
            f"  {wn}: same place {_fmt(o['same_place_inliers'])}; different rooms "
            f"{_fmt(o['different_room_inliers'])}"
        )
        print(
            f"    >= {o['inlier_threshold']} inliers: same {o['same_frac_ge_thr']:.2f}, different "
            f"{o['diff_frac_ge_thr']:.2f}; same-place PnP error m {_fmt(o['same_pose_err_m'], 3)}, "
            f"deg {_fmt(o['same_pose_err_deg'], 2)}"
        )
    out = args.json
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(results, indent=2, sort_keys=True) + "\n")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
