"""Multi-session merge on real data (7-Scenes redkitchen), against the truth.

Two mapping sessions from the mapping pass: A = frames 0-299, B = frames 200-499 (they
overlap in frames 200-299). B's map is re-expressed in a different world frame by a known,
seeded rigid transform (as if its odometry/SLAM had started elsewhere), then
`litevloc map merge A B` joins it back. Reported:

* frame error of the recovered alignment against the known transform (target <= 5 cm /
  0.5 deg), and the links used;
* robustness: 10 % of the cross-session links replaced by wrong ones (each moved 1-3 m and
  turned 10-40 deg), alignment change at B's keyframes (target <= 2 cm);
* localization of the held-out query pass (frames 500-999, every 10th; GL from no prior)
  in the merged map vs in a single-session map built from frames 0-499 (target: medians
  within 1 cm);
* merge time (target <= 5 min on 2 CPUs; say whether the machine was loaded).

    python bench/merge.py [--queries 500:1000:10] [--config 7scenes]

`--world floor` runs the simulator case of issue #18 instead: the world's mapping pass
(`sim record --pass map --seed 0`) is cut into two sessions that overlap in one or two rooms
(A = the first 55 % of its frames, B = the last 55 %); B's map is expressed in its own
odometry frame (origin and heading of the robot where B starts, gravity-aligned, as a
robot's odometry starts at its start pose) and merged into A's (the world frame). Reported
as above, plus the held-out query pass (`--pass query --seed 5`, GL from no prior) split by
where each query stands (a room only A mapped, only B, both, a corridor), and navigation from
a room only A mapped to every room only B mapped in the merged map vs the single-session map
of the whole pass (`sim navigate --map`, LiteVLoc and ground-truth localization).

    python bench/merge.py --world floor [--sim-queries 0::20] [--skip-nav]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

import numpy as np
from _common import OUT, ROOT, litevloc, print_table, require_7scenes, write_json
from numpy.typing import NDArray

from litevloc.base.frames import parse_frames
from litevloc.base.geometry import invert, make_T, relative_pose_error, so3_exp
from litevloc.base.params.map_maintenance import MergeParams
from litevloc.config import load_config
from litevloc.hw.streams.mcap_io import TOPIC_COLOR, McapSource
from litevloc.pipelines.localization.vloc import VisualLocalizer
from litevloc.pipelines.topomap.io import load_map
from litevloc.pipelines.topomap.map_save import save_map
from litevloc.pipelines.topomap.merge import Link, align, find_links, join_maps, transform_map
from litevloc.pipelines.topomap.types import TopoMap
from litevloc.runtime.sources import open_source
from litevloc.runtime.tools.posed import posed_frames
from litevloc.runtime.vloc_models import ModelBundle, check_map_models, load_bundle, second_look_for
from litevloc.sim.world import World, load_world

MAPS = ROOT / "out" / "maps"
SIM = ROOT / "out" / "merge_sim"


def build(data: Path, frames: str, out: Path, config: str) -> Path:
    if not (out / "manifest.json").is_file():
        print(f"building {out} from frames {frames} ...", flush=True)
        subprocess.run([sys.executable, "-m", "litevloc.cli.main", "map", "build", str(data), "--frames",
                        frames, "-o", str(out), "--config", config, "--force"], check=True)
    return out


def max_shift_m(T1: np.ndarray, T2: np.ndarray, B: TopoMap) -> float:
    """Largest displacement of B's keyframe centres between two alignments."""
    p = B.positions
    a = p @ T1[:3, :3].T + T1[:3, 3]
    b = p @ T2[:3, :3].T + T2[:3, 3]
    return float(np.linalg.norm(a - b, axis=1).max())


def wrong_links(links: list[Link], fraction: float, rng: np.random.Generator) -> list[Link]:
    n_bad = max(1, round(fraction * len(links)))
    out = list(links)
    for k in rng.choice(len(links), size=n_bad, replace=False):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        dT = make_T(so3_exp(axis * np.radians(rng.uniform(10, 40))), rng.normal(size=3) / np.sqrt(3) *
                    rng.uniform(1, 3))
        ln = out[k]
        out[k] = Link(ln.a, ln.b, dT @ ln.T_A_B, ln.inliers, ln.similarity)
    return out


def localize_queries(m: TopoMap, bundle: ModelBundle, cfg_name: str, data: Path, frames: str,
                     ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """GL from no prior on every posed query frame: (N, 3) true camera positions and (N, 2)
    errors (metres, degrees; NaN where no pose was accepted)."""
    cfg = load_config(cfg_name)
    loc = VisualLocalizer(m, cfg.localization, bundle.extract, bundle.describe, bundle.match,
                          second_look=second_look_for(m, cfg.models, cfg.localization, bundle))
    where, errs = [], []
    src = open_source(data, parse_frames(frames), strict=True, rgbd_calibration=cfg.rgbd_calibration)
    for frame, T in posed_frames(src):
        if T is None:
            continue
        res = loc.localize_global(frame.t_ns, frame.color, frame.depth, frame.K)
        ok = res.accepted and res.T_map_camera is not None
        errs.append(relative_pose_error(res.T_map_camera, T) if ok else (np.nan, np.nan))
        where.append(T[:3, 3])
    return np.asarray(where, np.float64).reshape(-1, 3), np.asarray(errs, np.float64).reshape(-1, 2)


def summarize(e: NDArray[np.float64]) -> dict[str, float]:
    """Accepted count and median/max error of (N, 2) errors with NaN for not accepted."""
    ok = e[np.isfinite(e[:, 0])]
    return {"queries": len(e), "accepted": len(ok),
            "median_cm": 100 * float(np.median(ok[:, 0])) if len(ok) else float("nan"),
            "median_deg": float(np.median(ok[:, 1])) if len(ok) else float("nan"),
            "max_cm": 100 * float(ok[:, 0].max()) if len(ok) else float("nan")}


def localize_all(m: TopoMap, bundle: ModelBundle, cfg_name: str, data: Path, frames: str) -> dict[str, float]:
    return summarize(localize_queries(m, bundle, cfg_name, data, frames)[1])


def gl_text(r: dict[str, float]) -> str:
    return f"{r['accepted']}/{r['queries']}, median {r['median_cm']:.2f} cm / {r['median_deg']:.2f} deg"


def merge_and_measure(A: TopoMap, B: TopoMap, T_A_B_true: NDArray[np.float64], bundle: ModelBundle,
                      ) -> tuple[TopoMap, dict[str, Any], list[list[str]]]:
    """Link, align and join B (in its own frame) into A's; frame error against the truth and
    the alignment change with 10 % wrong links (5 draws). Returns the merged map, the JSON
    fields and the table rows."""
    params = MergeParams()
    t0 = time.perf_counter()
    links, tried = find_links(A, B, bundle.match, params)
    t_links = time.perf_counter() - t0
    al = align(links, B, params)
    merged, report = join_maps(A, transform_map(B, al.T_A_B), links, al, params)
    t_merge = time.perf_counter() - t0
    dt, dr = relative_pose_error(al.T_A_B, T_A_B_true)
    shifts = []
    for trial in range(5):
        bad = wrong_links(links, 0.10, np.random.default_rng(100 + trial))
        shifts.append(max_shift_m(al.T_A_B, align(bad, B, params).T_A_B, B))
    rows = [
        ["frame error vs truth", f"{100 * dt:.2f} cm / {dr:.3f} deg", "<= 5 cm / 0.5 deg"],
        ["links consistent / verified / tried", f"{int(al.consistent.sum())} / {len(links)} / {tried}", ""],
        ["alignment change, 10 % wrong links (5 draws, max)", f"{100 * max(shifts):.2f} cm", "<= 2 cm"],
        ["keyframes A + B -> merged (duplicates dropped)",
         f"{A.n_nodes} + {B.n_nodes} -> {merged.n_nodes} ({report.nodes_dropped})", ""],
        ["cross-session covisibility / connectivity edges",
         f"{report.cross_covisibility_edges} / {report.cross_connectivity_edges}", ""],
        ["merge time (links / total)", f"{t_links:.1f} s / {t_merge:.1f} s", "<= 300 s"],
    ]
    fields = {
        "frame_error_m": dt, "frame_error_deg": dr, "links_tried": tried, "links_verified": len(links),
        "links_consistent": int(al.consistent.sum()), "wrong_links_shift_m": shifts,
        "nodes_a": A.n_nodes, "nodes_b": B.n_nodes, "nodes_merged": merged.n_nodes,
        "nodes_dropped": report.nodes_dropped, "cross_covisibility_edges": report.cross_covisibility_edges,
        "cross_connectivity_edges": report.cross_connectivity_edges, "seconds_links": t_links,
        "seconds_merge": t_merge, "T_A_B_true": T_A_B_true.tolist(), "T_A_B": al.T_A_B.tolist(),
    }
    return merged, fields, rows


def real_case(args: argparse.Namespace) -> None:
    """7-Scenes: A = frames 0-299, B = 200-499 moved by a known seeded transform."""
    data = require_7scenes()
    rng = np.random.default_rng(args.seed)
    path_a = build(data, "0:300", MAPS / "merge_A", args.config)
    path_b = build(data, "200:500", MAPS / "merge_B", args.config)
    path_full = build(data, "0:500", MAPS / "merge_single", args.config)
    cfg = load_config(args.config)
    bundle = load_bundle(cfg.models)
    A = check_map_models(load_map(path_a), bundle)
    B_true = check_map_models(load_map(path_b), bundle)
    # session B in its own world frame: the known transform T_B_A (B's frame from A's)
    T_B_A = make_T(so3_exp(rng.normal(size=3) * np.radians(40)), rng.uniform(-5, 5, size=3))
    B = transform_map(B_true, T_B_A)
    save_map(B, MAPS / "merge_B_moved", overwrite=True)
    merged, fields, rows = merge_and_measure(A, B, invert(T_B_A), bundle)
    merged = check_map_models(load_map(save_map(merged, MAPS / "merge_merged", overwrite=True)), bundle)
    single = check_map_models(load_map(path_full), bundle)
    loc_merged = localize_all(merged, bundle, args.config, data, args.queries)
    loc_single = localize_all(single, bundle, args.config, data, args.queries)
    rows += [
        ["GL on held-out queries, merged map", gl_text(loc_merged), ""],
        ["GL on held-out queries, single-session map (0-499)", gl_text(loc_single), "merged within 1 cm"],
    ]
    print_table("map merge, 7-Scenes redkitchen: A = frames 0-299, B = 200-499 in another frame",
                ["what", "measured", "target"], rows)
    write_json("merge", {**fields, "localize_merged": loc_merged, "localize_single": loc_single,
                         "queries": args.queries, "config": args.config})


def odometry_frame(T_world_camera: NDArray[np.float64]) -> NDArray[np.float64]:
    """T_world_odom of a robot whose odometry starts where this camera is: origin below the
    camera on the ground plane (z = 0), x along the camera's heading, z up."""
    f = T_world_camera[:3, 2]
    yaw = float(np.arctan2(f[1], f[0]))
    c, s_ = np.cos(yaw), np.sin(yaw)
    return make_T(np.array([[c, -s_, 0.0], [s_, c, 0.0], [0.0, 0.0, 1.0]]),
                  np.array([T_world_camera[0, 3], T_world_camera[1, 3], 0.0]))


def rooms_of(world: World, xyz: NDArray[np.float64]) -> list[str]:
    """Room name (or "" outside rooms) of each (N, 3) world position."""
    out = []
    for p in xyz:
        label = world.region_at(p[:2])
        reg = world.regions.get(label)
        out.append(reg.name if reg is not None and reg.kind == "room" else "")
    return out


def sim_case(args: argparse.Namespace) -> None:
    """The simulator case (see the module docstring)."""
    world_name, cfg_name = args.world, args.sim_config
    d = SIM / world_name
    d.mkdir(parents=True, exist_ok=True)
    cfg_args = ("--config", cfg_name)
    recs = {"map": ("map", 0), "query": ("query", 5)}
    for name, (pas, seed) in recs.items():
        if not (d / f"{name}.mcap").is_file():
            litevloc("sim", "record", world_name, "--pass", pas, "--seed", str(seed), "-o",
                      str(d / f"{name}.partial.mcap"), *cfg_args)
            (d / f"{name}.partial.mcap").replace(d / f"{name}.mcap")
    n = McapSource(d / "map.mcap").topic_counts[TOPIC_COLOR]
    a_end, b_start = round(n * (0.5 + args.overlap / 2)), round(n * (0.5 - args.overlap / 2))
    paths = {"A": (f"0:{a_end}", d / "map_A"), "B": (f"{b_start}:{n}", d / "map_B"), "single": (":", d / "map_single")}
    for frames, out in paths.values():
        if not (out / "manifest.json").is_file():
            litevloc("map", "build", str(d / "map.mcap"), "--frames", frames, "-o", str(out), "--force", *cfg_args)
    cfg = load_config(cfg_name)
    bundle = load_bundle(cfg.models)
    A = check_map_models(load_map(paths["A"][1]), bundle)
    B_world = check_map_models(load_map(paths["B"][1]), bundle)
    first = next(posed_frames(open_source(d / "map.mcap", parse_frames(f"{b_start}:{b_start + 1}"), strict=True)))
    if first[1] is None:
        raise SystemExit(f"frame {b_start} of {d / 'map.mcap'} has no ground-truth pose")
    T_world_B = odometry_frame(first[1])
    B = transform_map(B_world, invert(T_world_B))  # session B as its own odometry frame sees it
    save_map(B, d / "map_B_odom", overwrite=True)
    merged, fields, rows = merge_and_measure(A, B, T_world_B, bundle)
    merged = check_map_models(load_map(save_map(merged, d / "map_merged", overwrite=True)), bundle)  # as a user has it
    single = check_map_models(load_map(paths["single"][1]), bundle)
    world = load_world(world_name)
    rooms_a = {r for r in rooms_of(world, A.positions) if r}
    rooms_b = {r for r in rooms_of(world, B_world.positions) if r}
    rows.insert(0, ["rooms mapped by A / B / both", f"{len(rooms_a)} / {len(rooms_b)} / "
                    f"{len(rooms_a & rooms_b)} ({', '.join(sorted(rooms_a & rooms_b))})", "one or two"])
    where, e_m = localize_queries(merged, bundle, cfg_name, d / "query.mcap", args.sim_queries)
    _, e_s = localize_queries(single, bundle, cfg_name, d / "query.mcap", args.sim_queries)
    q_rooms = rooms_of(world, where)
    groups = {
        "A only": np.array([r in rooms_a - rooms_b for r in q_rooms]),
        "B only": np.array([r in rooms_b - rooms_a for r in q_rooms]),
        "both": np.array([r in rooms_a & rooms_b for r in q_rooms]),
        "corridors": np.array([r == "" for r in q_rooms]),
        "all": np.ones(len(q_rooms), dtype=bool),
    }
    gl = {}
    for g, mask in groups.items():
        gl[g] = {"merged": summarize(e_m[mask]), "single": summarize(e_s[mask])}
        rows.append([f"GL on query pass ({g}): merged | single", f"{gl_text(gl[g]['merged'])} | "
                     f"{gl_text(gl[g]['single'])}", "merged median within 1 cm" if g == "all" else ""])
    title = f"map merge, simulator `{world_name}`: two sessions of the mapping pass, B in its own odometry frame"
    print_table(title, ["what", "measured", "target"], rows)
    result = {**fields, "frames": n, "session_a_frames": paths["A"][0], "session_b_frames": paths["B"][0],
              "rooms_a": sorted(rooms_a), "rooms_b": sorted(rooms_b), "gl": gl, "queries": args.sim_queries,
              "config": cfg_name}
    write_json(f"merge_{world_name}", result)
    if args.skip_nav:
        return
    order = [r for r in rooms_of(world, A.positions) if r in rooms_a - rooms_b]
    goals = sorted(rooms_b - rooms_a)
    start = order[0]
    nav: dict[str, Any] = {}
    for name, m_path in (("merged", d / "map_merged"), ("single", paths["single"][1])):
        out_json = d / f"nav_{name}.json"
        cmd = ["sim", "navigate", world_name, "--map", str(m_path), "--start", start, "--goals", *goals,
               "--localization", "both", "--json", str(out_json), "-o", str(OUT / f"merge_{world_name}_nav_{name}.png"),
               *cfg_args]
        print(f"$ litevloc {' '.join(cmd)}", flush=True)
        out_json.unlink(missing_ok=True)
        # exit code 1 = not every goal reached (the JSON says which); anything else is a failure
        rc = subprocess.run([sys.executable, "-m", "litevloc.cli.main", *cmd]).returncode
        if rc not in (0, 1) or not out_json.is_file():
            raise SystemExit(f"`litevloc {' '.join(cmd)}` failed with exit code {rc}")
        nav[name] = json.loads(out_json.read_text())
    print_table(f"navigation from {start} (mapped by A only) to the {len(goals)} rooms only B mapped",
                ["map", "reached (LiteVLoc, ground truth), collisions"],
                [[name, nav_text(nav[name])] for name in ("merged", "single")])
    write_json(f"merge_{world_name}", {**result, "navigation": {"start": start, "goals": goals, **nav}})


def nav_text(r: dict[str, Any]) -> str:
    """`sim navigate --json` summary: goals reached with LiteVLoc and with ground truth."""
    b = r.get("baseline", {})
    return (f"LiteVLoc {r['goals_reached']}/{r['goals_total']}, ground truth {b.get('goals_reached')}/"
            f"{b.get('goals_total')}, {r['collisions']} collisions")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--queries", default="500:1000:10", help="held-out query frames (GL from no prior)")
    ap.add_argument("--config", default="7scenes")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--world", default=None, help="run the simulator case on this world instead (e.g. floor)")
    ap.add_argument("--sim-config", default="default", help="simulator case: preset")
    ap.add_argument("--overlap", type=float, default=0.10, help="simulator case: share of the mapping pass in both")
    ap.add_argument("--sim-queries", default="0::20", help="simulator case: query-pass frames (GL from no prior)")
    ap.add_argument("--skip-nav", action="store_true", help="simulator case: no navigation runs")
    args = ap.parse_args()
    if args.world:
        sim_case(args)
    else:
        real_case(args)


if __name__ == "__main__":
    main()
