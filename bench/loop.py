"""A 200 m route: map the `loop` world's ring corridor once, localize a query lap driven in
another lane through the full runtime, then navigate to goal images along it.

    .venv/bin/python bench/loop.py [--json out/bench/loop.json] [--goals 5] [--skip-nav] [--set K=V ...]
        [--fault SPEC ...]

1. Map: `litevloc map build sim:loop?pass=loop&seed=0` (one lap of the ~200 m ring, the
   default preset; depth-only pass 1, colour for the keyframes only). Map size in total and
   per 100 m of the mapping route, split into images / features / graph + descriptors
   (+ occupancy grid and arrays, `other`).
2. Query: pass `loop-lane` (seed 1: its own lighting, image noise and seeded odometry drift;
   the lap the same way round, 0.3 m off the centre line; `--query-pass loop-back` drives it
   the other way round, where a forward-looking camera faces every wall from the side the
   mapping lap never saw: measured 0/111 accepted, VPR retrieving places ~38 m away that the
   joint check refused) through the runtime as `litevloc
   replay --map` runs it: threads (VLoc in its own thread, frames dropped while it is busy),
   GTSAM fusion, poses published over Zenoh on a free loopback port, in real time (`--rate 1`;
   at rate 0 VLoc sees fewer frames per second of sensor time). Accepted VLoc poses are
   recorded by wrapping the localizer's `process`.
   * `vloc_ate_m`: RMSE of accepted VLoc camera positions vs ground truth (no alignment);
   * `fused_ate_m`: RMSE of the published fused camera positions vs ground truth;
   * `odometry_ate_m`: RMSE of the odometry alone (anchored at the true start pose);
   * `localized_fraction`: accepted VLoc poses / frames VLoc processed (and of all frames).
   * `first_fix_s`, `longest_without_fix_s`: sensor seconds to the first accepted VLoc pose, and
     the longest stretch without one (the robot on odometry alone), `longest_without_fix_at_s`
     where that stretch starts (sensor seconds from the lap's start);
   * `fused_err_p90_m`, `fused_err_max_m`, `fused_err_max_at_s`: the fused error's tail and
     when its maximum was.
3. Navigation: `--goals` goal images rendered at equal arc length along the mapping route
   (facing along it), driven to in order from the route's start with LiteVLoc localization
   (`runtime.tools.sim_navigation.run_navigation`, as `sim navigate`), and again with ground-truth
   localization as the baseline (`--no-baseline`: LiteVLoc only).

Prints a table and writes JSON (all numbers measured in this run; nothing here was tuned on
the loop world).
"""

from __future__ import annotations

import argparse
import json
import socket
import sys
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from _common import run_meta


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _rmse(err: np.ndarray) -> float:
    return float(np.sqrt(np.mean(err**2))) if len(err) else float("nan")


def build_map(out: Path, config: str) -> dict[str, Any]:
    from litevloc.config import load_config
    from litevloc.runtime.tools import map_building, outputs

    js = out / "map.json"
    t0 = time.perf_counter()
    req = map_building.MapBuildRequest(src="sim:loop?pass=loop&seed=0", output=out / "map", force=True, config=config)
    outputs.write_json(js, map_building.build_map(req, load_config(config)))
    info = json.loads(js.read_text())
    info["wall_s"] = time.perf_counter() - t0
    return info


def query(map_dir: Path, config: str, pass_name: str = "loop-lane", rate: float = 1.0,
          overrides: tuple[str, ...] = (), faults: tuple[str, ...] = ()) -> dict[str, Any]:
    """The query lap through the threaded runtime (as `litevloc replay --map`), the
    configuration `config` with `overrides` (key=value) and `faults` injected (as `--fault`)."""
    from litevloc.base.geometry import invert
    from litevloc.config import load_config
    from litevloc.runtime.service.app import build_app, with_endpoints
    from litevloc.runtime.service.faults import FaultInjector
    from litevloc.sim.source import SimSequenceSource
    from litevloc.sim.world import load_world

    cfg = with_endpoints(load_config(config, overrides), [f"tcp/127.0.0.1:{_free_port()}"], [], None)
    src = SimSequenceSource(load_world("loop"), pass_name, 1, params=cfg.sim)
    injector = FaultInjector(list(faults))  # parsed before the (slow) model loading
    app = build_app(cfg, map_dir, src, rate)
    injector.apply(app.service)
    vloc: list[tuple[int, bool, np.ndarray | None]] = []
    how: list[str] = []  # per accepted result: "local", "global" or "global+prior" (one keyframe + the prior)
    detail: list[dict[str, Any]] = []  # per accepted result: what accepted it, and the prior it had
    inner = app.service.vloc_fn  # the service's vloc(frame, prior): in this process or the VLoc process

    def process(frame: Any, prior: Any) -> Any:
        r = inner(frame, prior)
        vloc.append((int(r.t_ns), bool(r.accepted), None if r.T_map_camera is None else np.array(r.T_map_camera)))
        if r.accepted and r.T_map_camera is not None:
            how.append("global+prior" if "agrees with the prior" in getattr(r, "stop_reason", "")
                       else str(getattr(r, "mode", "")))
            T_prior = getattr(prior, "T_map_camera", None)
            detail.append({"t_s": round(int(r.t_ns) * 1e-9, 3), "ref_node": int(r.ref_node),
                           "keyframes": [int(k) for k in r.keyframes], "inliers": int(r.n_inliers),
                           "matches": int(r.n_matches), "reason": str(r.reason),
                           "prior_age_s": None if prior is None else round(float(prior.age_s), 2),
                           "prior_sigma_m": None if getattr(prior, "cov_position", None) is None else
                           round(float(np.sqrt(np.linalg.eigvalsh(prior.cov_position)[-1])), 3),
                           "from_prior_m": None if T_prior is None else
                           round(float(np.linalg.norm(np.asarray(r.T_map_camera)[:3, 3] - T_prior[:3, 3])), 3)})
        return r

    app.service.vloc_fn = process
    t0 = time.perf_counter()
    try:
        res = app.service.run()
    finally:
        app.close()
    wall = time.perf_counter() - t0
    rec = app.recorder
    acc = [(t, T) for t, ok, T in vloc if ok and T is not None]
    v_err = np.array([np.linalg.norm(T[:3, 3] - src._cam_pose(t)[:3, 3]) for t, T in acc])
    f_err = np.array([np.linalg.norm((T @ app.T_base_camera)[:3, 3] - src._cam_pose(t)[:3, 3])
                      for t, T in zip(rec.fused_t, rec.fused_T, strict=True)])
    run = src.run
    T_wo = run.T_world_base[0] @ invert(run.T_odom_base[0])
    o_err = np.linalg.norm((T_wo @ run.T_odom_base)[:, :3, 3] - run.T_world_base[:, :3, 3], axis=1)
    c = app.service.counters
    return {
        "ok": res.ok, "reason": res.reason, "wall_s": wall, "sensor_s": src.duration_s,
        "frames": src.frame_count(), "vloc_calls": len(vloc), "vloc_accepted": len(acc),
        "localized_fraction": len(acc) / max(len(vloc), 1),
        "localized_fraction_of_all_frames": len(acc) / max(src.frame_count(), 1),
        "vloc_ate_m": _rmse(v_err), "vloc_err_median_m": float(np.median(v_err)) if len(v_err) else None,
        "vloc_err_p90_m": float(np.percentile(v_err, 90)) if len(v_err) else None,
        "vloc_accepted_over_0_5m": int((v_err > 0.5).sum()),  # wrong places accepted (repetitive corridor)
        "vloc_accepted_by_mode": {m: how.count(m) for m in sorted(set(how))},
        "vloc_over_0_5m_by_mode": {m: int(sum(e > 0.5 for e, h in zip(v_err, how, strict=True) if h == m))
                                   for m in sorted(set(how))},
        "vloc_err_max_m": float(v_err.max()) if len(v_err) else None,
        # accepted poses more than 0.5 m off: how each was accepted (diagnosis of the wrong places)
        "vloc_outliers": [{"err_m": round(float(e), 3), "mode": h, **d}
                          for e, h, d in zip(v_err, how, detail, strict=True) if e > 0.5],
        "fused_ate_m": _rmse(f_err), "fused_err_median_m": float(np.median(f_err)) if len(f_err) else None,
        "fused_err_p90_m": float(np.percentile(f_err, 90)) if len(f_err) else None,
        "fused_err_max_m": float(f_err.max()) if len(f_err) else None,
        "fused_err_max_at_s": float((rec.fused_t[int(f_err.argmax())] - int(run.t_ns[0])) * 1e-9)
        if len(f_err) else None,
        "fused_poses": len(f_err), "odometry_ate_m": _rmse(o_err), "odometry_final_error_m": float(o_err[-1]),
        "odometry_max_error_m": float(o_err.max()),
        **_time_without_fix(np.array([t for t, _, _ in vloc]) * 1e-9, np.array([t for t, _ in acc]) * 1e-9,
                            int(run.t_ns[0]) * 1e-9),
        "counters": {k: c[k] for k in ("frames_in", "odometry_in", "vloc_calls", "vloc_accepted",
                                       "fusion_accepted", "poses_published", "prior_waits_timed_out") if k in c},
        "faults": list(faults), "faults_applied": dict(injector.counts),
        "fusion_vloc_by_reason": app.fusion.stats()["vloc_by_reason"],
    }


def _time_without_fix(t_calls_s: np.ndarray, t_fixes_s: np.ndarray, t0_s: float) -> dict[str, float | None]:
    """Sensor seconds from the first VLoc call to the first accepted pose, and the longest
    stretch between VLoc calls `t_calls_s` without an accepted pose (`t_fixes_s`, the lap's
    end included): the time a robot runs on odometry alone, and when it started (after `t0_s`)."""
    if len(t_calls_s) == 0:
        return {"first_fix_s": None, "longest_without_fix_s": None, "longest_without_fix_at_s": None}
    edges = np.concatenate([[t_calls_s[0]], np.sort(t_fixes_s), [t_calls_s[-1]]])
    i = int(np.argmax(np.diff(edges)))
    return {"first_fix_s": float(t_fixes_s.min() - t_calls_s[0]) if len(t_fixes_s) else None,
            "longest_without_fix_s": float(edges[i + 1] - edges[i]),
            "longest_without_fix_at_s": float(edges[i] - t0_s)}


def loop_goals(world: Any, cfg: Any, n_goals: int) -> tuple[list[Any], Any, list[float]]:
    """(goals, the mapping route, each goal's arc length in metres): `n_goals` goal images
    rendered at equal arc length along the loop's mapping route, facing along it (seeded)."""
    from litevloc.runtime.tools.sim_driver import Goal
    from litevloc.sim.realism import sample_lighting
    from litevloc.sim.render import Renderer
    from litevloc.sim.simulator import camera_pose, render_frame
    from litevloc.sim.source import SimSequenceSource

    route = SimSequenceSource(world, "loop", 0, params=cfg.sim).run
    xy = route.T_world_base[:, :2, 3]
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))])
    lap = s[-1] - 10.0  # the pass drives 10 m past its start
    ren = Renderer(world)
    light = sample_lighting(cfg.sim.realism, np.random.default_rng([7, 11]))
    goals = []
    for k in range(n_goals):
        i = int(np.searchsorted(s, lap * (k + 1) / (n_goals + 1)))
        T = route.T_world_base[i]
        f = render_frame(ren, camera_pose(T, 0.0, 0.0, cfg.sim), cfg.sim.intrinsics, cfg.sim.realism, light,
                         np.random.default_rng([7, 19, k]), 0, k)
        ok, buf = cv2.imencode(".jpg", f.color[:, :, ::-1], [cv2.IMWRITE_JPEG_QUALITY, 90])
        assert ok
        goals.append(Goal(f"loop_{k}", buf.tobytes(), T))
    return goals, route, [round(lap * (k + 1) / (n_goals + 1), 1) for k in range(n_goals)]


def navigate(map_dir: Path, config: str, n_goals: int, baseline: bool,
             overrides: tuple[str, ...] = ()) -> dict[str, Any]:
    """LiteVLoc's navigation run (summary dict, as `sim navigate`'s JSON) and, with `baseline`,
    the same goals driven with ground-truth localization (`baseline`) and the time and path
    ratios over the goals both reached (`ratios`): the goal images are placed on the map in
    the same way in both runs, so a goal the baseline misses too is lost to its image or the
    map, not to the localization."""
    from litevloc.config import load_config
    from litevloc.runtime.tools.sim_navigation import goal_ratios, run_navigation
    from litevloc.sim.world import load_world

    cfg = load_config(config, overrides)
    world = load_world("loop")
    goals, route, arc = loop_goals(world, cfg, n_goals)
    run = run_navigation(world, cfg, map_dir, goals, route.T_world_base[0], "litevloc", cfg.sim_navigation)
    out = run.summary()
    out.pop("trace", None)
    out["goal_arc_m"] = arc
    if baseline:
        base = run_navigation(world, cfg, map_dir, goals, route.T_world_base[0], "ground-truth",
                              cfg.sim_navigation).summary()
        base.pop("trace", None)
        out["baseline"] = base
        out["ratios"] = goal_ratios(out["goals"], base["goals"])
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--json", type=Path, default=Path("out/bench/loop.json"))
    ap.add_argument("--out-dir", type=Path, default=Path("out/bench/loop"))
    ap.add_argument("--config", default="default")
    ap.add_argument("--set", dest="overrides", action="append", default=[], help="KEY=VALUE (query and navigation)")
    ap.add_argument("--goals", type=int, default=5)
    ap.add_argument("--fault", action="append", default=[], metavar="SPEC",
                    help="fault injected into the query lap, as `replay --fault` (e.g. slow_vloc@30:300,delay_ms=4000)")
    ap.add_argument("--skip-nav", action="store_true", help="map and query pass only")
    ap.add_argument("--no-baseline", action="store_true",
                    help="navigation with LiteVLoc only (no ground-truth localization run to compare)")
    ap.add_argument("--reuse-map", action="store_true", help="use OUT_DIR/map if it exists")
    ap.add_argument("--query-pass", default="loop-lane", choices=("loop-lane", "loop-back"))
    ap.add_argument("--rate", type=float, default=1.0, help="query replay speed (1 = real time, as on the robot; "
                    "0 = as fast as possible: VLoc then sees fewer frames per second of sensor time)")
    args = ap.parse_args()
    from litevloc.pipelines.topomap.io import load_map, storage_summary
    from litevloc.sim.source import SimSequenceSource
    from litevloc.sim.world import load_world

    args.out_dir.mkdir(parents=True, exist_ok=True)
    map_dir = args.out_dir / "map"
    res: dict[str, Any] = {}
    if not (args.reuse_map and (map_dir / "manifest.json").is_file()):
        res["build"] = build_map(args.out_dir, args.config)
    st = storage_summary(map_dir)
    route = SimSequenceSource(load_world("loop"), "loop", 0).run.T_world_base[:, :2, 3]
    route_m = float(np.linalg.norm(np.diff(route, axis=0), axis=1).sum())
    total = sum(st.values())
    per = 100.0 / route_m
    res.update({
        "route_m": route_m, "map_nodes": load_map(map_dir).n_nodes, "map_bytes": total,
        "map_bytes_per_100m": total * per,
        "map_split_bytes": {"images": st["image_bytes"], "features": st["feature_bytes"],
                            "graph_descriptors": st["graph_bytes"] + st["descriptor_bytes"],
                            "other": st["other_bytes"]},
        "map_split_bytes_per_100m": {"images": st["image_bytes"] * per, "features": st["feature_bytes"] * per,
                                     "graph_descriptors": (st["graph_bytes"] + st["descriptor_bytes"]) * per,
                                     "other": st["other_bytes"] * per},
    })
    print(f"map: {res['map_nodes']} nodes over {route_m:.0f} m, {total / 1e6:.2f} MB "
          f"({res['map_bytes_per_100m'] / 1e6:.2f} MB per 100 m: images "
          f"{res['map_split_bytes_per_100m']['images'] / 1e6:.2f}, features "
          f"{res['map_split_bytes_per_100m']['features'] / 1e6:.2f}, graph+descriptors "
          f"{res['map_split_bytes_per_100m']['graph_descriptors'] / 1e6:.3f}, other "
          f"{res['map_split_bytes_per_100m']['other'] / 1e6:.3f})", flush=True)
    q = query(map_dir, args.config, args.query_pass, args.rate, tuple(args.overrides), tuple(args.fault))
    q["pass"], q["rate"], q["overrides"] = args.query_pass, args.rate, list(args.overrides)
    res["query"] = q
    for k in ("vloc_ate_m", "fused_ate_m", "odometry_ate_m", "localized_fraction"):
        res[k] = q[k]
    print(f"query lap ({q['frames']} frames, {q['sensor_s']:.0f} s sensor, {q['wall_s']:.0f} s wall): VLoc "
          f"{q['vloc_accepted']}/{q['vloc_calls']} accepted ({100 * q['localized_fraction']:.0f} %), ATE VLoc "
          f"{100 * q['vloc_ate_m']:.1f} cm, fused {100 * q['fused_ate_m']:.1f} cm, odometry alone "
          f"{q['odometry_ate_m']:.2f} m (final {q['odometry_final_error_m']:.2f} m); first fix after "
          f"{q['first_fix_s']} s, longest without a fix {q['longest_without_fix_s']} s", flush=True)
    if not args.skip_nav:
        nav = navigate(map_dir, args.config, args.goals, not args.no_baseline, tuple(args.overrides))
        res["navigation"] = nav
        res["goals_reached"], res["goals_total"] = nav["goals_reached"], nav["goals_total"]
        print(f"navigation: {nav['goals_reached']}/{nav['goals_total']} goals, {nav['time_s']:.0f} s simulated, "
              f"{nav['path_length_m']:.0f} m, {nav['collisions']} collisions ({nav['wall_s']:.0f} s wall)")
        if "baseline" in nav:
            b, r = nav["baseline"], nav["ratios"]
            res["baseline_goals_reached"] = b["goals_reached"]
            print(f"  ground-truth localization: {b['goals_reached']}/{b['goals_total']} goals, {b['time_s']:.0f} s, "
                  f"{b['path_length_m']:.0f} m, {b['collisions']} collisions; over the {r['goals_compared']} goals "
                  f"both reached: path x{r['path_length']}, time x{r['time']}")
        for g in nav["goals"]:
            if g["outcome"] != "reached":
                print(f"  {g['name']}: {g['outcome']}: {g['reason']}")
    else:
        res["goals_reached"] = res["goals_total"] = None
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps({"meta": run_meta(), **res}, indent=2, sort_keys=True, default=float) + "\n")
    print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
