"""`litevloc demo`: the main job on the embedded default (a simulated office, no data needed).

1. record a mapping pass through the world (`sim record --pass map`),
2. build the map-lite map from it (`map build`),
3. record a query pass with another route and lighting (`sim record --pass query`),
4. run the onboard pipeline on the query pass (`replay --config`: threaded runtime, VLoc +
   fusion with odometry) and score the fused trajectory against ground truth,
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
    p.add_argument("--vloc-every", type=int, default=5, metavar="N",
                   help="localize every N-th query frame (15 Hz camera / 5 = 3 Hz VLoc, as onboard)")
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
    from litevloc.pipelines.evaluation.trajectory import associate, ate, read_tum
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
    traj = out / "vloc.txt"
    times["localize"] = _step("localize the query pass against the map", [
        "localize", str(map_dir), str(query_rec), "--frames", f"::{args.vloc_every}", "-o", str(traj), *cfg,
        "--json", str(out / "localize.json")])
    # Score against ground truth and plot.
    gt_t, gt_T = [], []
    for frame, T in posed_frames(open_source(query_rec)):
        if T is not None:
            gt_t.append(frame.t_ns * 1e-9)
            gt_T.append(T)
    est_t, est_T = read_tum(traj)
    summary: dict[str, Any] = {"world": args.world, "seconds": times,
                               "map": json.loads((out / "map.json").read_text()),
                               "localize": json.loads((out / "localize.json").read_text())}
    m = load_map(map_dir)
    paths = {"query pass (ground truth)": np.array(gt_T)[:, :3, 3]}
    if len(est_t):
        ia, ib = associate(est_t, np.array(gt_t), 0.01)
        res = ate(est_T[ia], np.array(gt_T)[ib], align=False)
        summary["vloc_error_m"] = {"rmse": res.rmse, "median": res.median, "max": res.max, "n": res.n}
        paths["LiteVLoc VLoc poses"] = est_T[:, :3, 3]
    png = plot_map(m, out / "demo.png", title=f"LiteVLoc demo: {args.world}", extra_paths=paths)
    summary["png"] = str(png)
    loc = summary["localize"]
    print("\n== LiteVLoc demo results")
    print(f"world {args.world}: map of {m.n_nodes} keyframes, {len(m.covis_edges)} covisibility / "
          f"{len(m.conn_edges)} connectivity edges")
    print(f"query pass: {loc['queries']} frames, {loc['accepted']} localized "
          f"({100 * loc['accepted'] / max(loc['queries'], 1):.0f} %)")
    if "vloc_error_m" in summary:
        e = summary["vloc_error_m"]
        print(f"position error of accepted VLoc poses: median {100 * e['median']:.1f} cm, "
              f"RMSE {100 * e['rmse']:.1f} cm, max {100 * e['max']:.1f} cm")
    print(f"plot: {png}")
    write_json(args.json or out / "demo.json", summary)
    return 0
