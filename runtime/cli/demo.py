"""`litevloc demo`: the main job on the embedded default (a simulated office, no data needed).

1. record a mapping pass through the world (`sim record --pass map`),
2. build the map-lite map from it (`map build`),
3. record a query pass with another route and lighting (`sim record --pass query`),
4. run the onboard service on the query pass in real time (`replay --map`: threaded
   runtime, VLoc + GTSAM fusion with odometry, poses published over Zenoh on loopback) and
   score the fused trajectory against ground truth,
5. write a top-down PNG of the map with the true and estimated trajectories, a JSON
   summary, and print a results table.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

from litevloc.runtime.cli.common import add_json_arg, write_json
from litevloc.runtime.cli.main import UserError


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="the main job: map and localize in the embedded simulated office")
    p.add_argument("--world", default="office", help="simulated world (default: office)")
    p.add_argument("-o", "--output", type=Path, default=Path("out/demo"), help="output folder")
    p.add_argument("--map-duration", type=float, default=None, metavar="S",
                   help="seconds of the mapping pass (default: the whole pass)")
    p.add_argument("--query-duration", type=float, default=60.0, metavar="S", help="seconds of the query pass")
    p.add_argument("--rate", type=float, default=1.0, help="real-time factor of the query replay (default 1)")
    p.add_argument("--config", default="default", help="preset or YAML (default: default)")
    add_json_arg(p)
    p.set_defaults(func=run)


def _step(title: str, argv: list[str]) -> float:
    from litevloc.runtime.cli.main import main

    print(f"\n== {title}: litevloc {' '.join(argv)}", flush=True)
    t0 = time.perf_counter()
    rc = main(argv)
    if rc != 0:
        raise UserError(f"demo step '{title}' failed with exit code {rc}")
    return time.perf_counter() - t0


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from litevloc.pipelines.evaluation.trajectory import read_tum
    from litevloc.pipelines.topomap.io import load_map
    from litevloc.pipelines.topomap.plot import plot_map
    from litevloc.runtime.posed import posed_frames
    from litevloc.runtime.sources import open_source

    out: Path = args.output
    out.mkdir(parents=True, exist_ok=True)
    cfg = ["--config", args.config]
    times: dict[str, float] = {}
    map_rec, query_rec, map_dir = out / "map.mcap", out / "query.mcap", out / "map"
    dur = ["--duration", str(args.map_duration)] if args.map_duration else []
    times["record_map_pass"] = _step("record the mapping pass", [
        "sim", "record", args.world, "--pass", "map", "--seed", "0", "-o", str(map_rec), *dur, *cfg,
        "--json", str(out / "record_map.json")])
    times["build_map"] = _step("build the map", [
        "map", "build", str(map_rec), "-o", str(map_dir), "--force", *cfg, "--json", str(out / "map.json")])
    times["record_query_pass"] = _step("record a query pass (other route and lighting)", [
        "sim", "record", args.world, "--pass", "query", "--seed", "1", "-o", str(query_rec),
        "--duration", str(args.query_duration), *cfg, "--json", str(out / "record_query.json")])
    traj = out / "fused.txt"
    times["replay_runtime"] = _step("run the onboard service on the query pass (real time, VLoc + fusion + Zenoh)", [
        "replay", str(query_rec), "--map", str(map_dir), "-o", str(traj), "--rate", str(args.rate), *cfg,
        "--json", str(out / "replay.json")])
    rep = json.loads((out / "replay.json").read_text())
    summary: dict[str, Any] = {"world": args.world, "seconds": times,
                               "map": json.loads((out / "map.json").read_text()), "runtime": rep}
    # Plot the map with the true and the fused camera trajectories.
    from litevloc.config import load_config

    T_bc = load_config(args.config).fusion.T_base_camera()
    gt = np.array([T for _, T in posed_frames(open_source(query_rec)) if T is not None])
    m = load_map(map_dir)
    paths = {"query pass (ground truth)": gt[:, :3, 3]}
    if traj.is_file():
        _, fused = read_tum(traj)
        paths["LiteVLoc fused pose"] = (fused @ T_bc)[:, :3, 3]
    png = plot_map(m, out / "demo.png", title=f"LiteVLoc demo: {args.world}", extra_paths=paths)
    summary["png"] = str(png)
    c = rep.get("counters", {})
    dur = json.loads((out / "record_query.json").read_text()).get("simulated_seconds", args.query_duration)
    rows = [
        ("map", f"{m.n_nodes} keyframes, {len(m.covis_edges)} covisibility / {len(m.conn_edges)} connectivity edges"),
        ("query pass", f"{c.get('frames_in', 0)} frames, {c.get('odometry_in', 0)} odometry messages, {dur:.0f} s"),
        ("VLoc", f"{c.get('vloc_calls', 0)} queries ({c.get('vloc_calls', 0) / max(dur, 1e-9):.1f} Hz), "
                 f"{c.get('vloc_accepted', 0)} accepted, {c.get('fusion_accepted', 0)} fused, "
                 f"{rep.get('frames_dropped', 0)} stale frames dropped"),
        ("fused poses", f"{rep.get('fused_poses', 0)} published over Zenoh"),
    ]
    if "ate_m" in rep:
        a = rep["ate_m"]
        rows.append(("fused camera error", f"median {100 * a['median']:.1f} cm, RMSE {100 * a['rmse']:.1f} cm, "
                                           f"max {100 * a['max']:.1f} cm (no alignment)"))
    lat = rep.get("latency", {}).get("odometry_to_publish", {})
    if lat.get("count"):
        rows.append(("odometry -> pose latency", f"median {lat['median_ms']:.2f} ms, p99 {lat['p99_ms']:.2f} ms"))
    rows.append(("plot", str(png)))
    print("\n== LiteVLoc demo results")
    for k, v in rows:
        print(f"{k:<26} {v}")
    ok = bool(rep.get("ok")) and rep.get("fused_poses", 0) > 0
    summary["ok"] = ok
    write_json(args.json or out / "demo.json", summary)
    return 0 if ok else 1
