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
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import numpy as np
from _common import ROOT, print_table, require_7scenes, write_json

from litevloc.config import load_config
from litevloc.hw.streams.base import parse_frames
from litevloc.pipelines.geometry import invert, make_T, relative_pose_error, so3_exp
from litevloc.pipelines.localization.vloc import VisualLocalizer
from litevloc.pipelines.topomap.io import load_map, save_map
from litevloc.pipelines.topomap.merge import Link, MergeParams, align, find_links, join_maps, transform_map
from litevloc.pipelines.topomap.types import TopoMap
from litevloc.runtime.posed import posed_frames
from litevloc.runtime.sources import open_source
from litevloc.runtime.vloc_models import ModelBundle, check_map_models, load_bundle

MAPS = ROOT / "out" / "maps"


def build(data: Path, frames: str, out: Path, config: str) -> Path:
    if not (out / "manifest.json").is_file():
        print(f"building {out} from frames {frames} ...", flush=True)
        subprocess.run([sys.executable, "-m", "litevloc.runtime.cli.main", "map", "build", str(data), "--frames",
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


def localize_all(m: TopoMap, bundle: ModelBundle, cfg_name: str, data: Path, frames: str) -> dict[str, float]:
    cfg = load_config(cfg_name)
    loc = VisualLocalizer(m, cfg.localization, bundle.extract, bundle.describe, bundle.match)
    errs, n = [], 0
    src = open_source(data, parse_frames(frames), strict=True, rgbd_calibration=cfg.rgbd_calibration)
    for frame, T in posed_frames(src):
        if T is None:
            continue
        n += 1
        res = loc.localize_global(frame.t_ns, frame.color, frame.depth, frame.K)
        if res.accepted and res.T_map_camera is not None:
            errs.append(relative_pose_error(res.T_map_camera, T))
    e = np.asarray(errs).reshape(-1, 2)
    return {"queries": n, "accepted": len(e), "median_cm": 100 * float(np.median(e[:, 0])) if len(e) else np.nan,
            "median_deg": float(np.median(e[:, 1])) if len(e) else np.nan,
            "max_cm": 100 * float(e[:, 0].max()) if len(e) else np.nan}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--queries", default="500:1000:10", help="held-out query frames (GL from no prior)")
    ap.add_argument("--config", default="7scenes")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
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
    params = MergeParams()
    t0 = time.perf_counter()
    links, tried = find_links(A, B, bundle.match, params)
    t_links = time.perf_counter() - t0
    al = align(links, B, params)
    merged, report = join_maps(A, transform_map(B, al.T_A_B), links, al, params)
    t_merge = time.perf_counter() - t0
    save_map(merged, MAPS / "merge_merged", overwrite=True)
    dt, dr = relative_pose_error(al.T_A_B, invert(T_B_A))
    # robustness: 10 % wrong links
    shifts = []
    for trial in range(5):
        bad = wrong_links(links, 0.10, np.random.default_rng(100 + trial))
        al_bad = align(bad, B, params)
        shifts.append(max_shift_m(al.T_A_B, al_bad.T_A_B, B))
    single = check_map_models(load_map(path_full), bundle)
    loc_merged = localize_all(merged, bundle, args.config, data, args.queries)
    loc_single = localize_all(single, bundle, args.config, data, args.queries)
    rows = [
        ["frame error vs truth", f"{100 * dt:.2f} cm / {dr:.3f} deg", "<= 5 cm / 0.5 deg"],
        ["links consistent / verified / tried", f"{int(al.consistent.sum())} / {len(links)} / {tried}", ""],
        ["alignment change, 10 % wrong links (5 draws, max)", f"{100 * max(shifts):.2f} cm", "<= 2 cm"],
        ["keyframes A + B -> merged (duplicates dropped)",
         f"{A.n_nodes} + {B.n_nodes} -> {merged.n_nodes} ({report.nodes_dropped})", ""],
        ["cross-session covisibility / connectivity edges",
         f"{report.cross_covisibility_edges} / {report.cross_connectivity_edges}", ""],
        ["merge time (links / total)", f"{t_links:.1f} s / {t_merge:.1f} s", "<= 300 s"],
        ["GL on held-out queries, merged map", f"{loc_merged['accepted']}/{loc_merged['queries']}, median "
         f"{loc_merged['median_cm']:.2f} cm / {loc_merged['median_deg']:.2f} deg", ""],
        ["GL on held-out queries, single-session map (0-499)", f"{loc_single['accepted']}/{loc_single['queries']}, "
         f"median {loc_single['median_cm']:.2f} cm / {loc_single['median_deg']:.2f} deg", "merged within 1 cm"],
    ]
    print_table("map merge, 7-Scenes redkitchen: A = frames 0-299, B = 200-499 in another frame",
                ["what", "measured", "target"], rows)
    write_json("merge", {
        "frame_error_m": dt, "frame_error_deg": dr, "links_tried": tried, "links_verified": len(links),
        "links_consistent": int(al.consistent.sum()), "wrong_links_shift_m": shifts,
        "nodes_a": A.n_nodes, "nodes_b": B.n_nodes, "nodes_merged": merged.n_nodes,
        "nodes_dropped": report.nodes_dropped, "cross_covisibility_edges": report.cross_covisibility_edges,
        "cross_connectivity_edges": report.cross_connectivity_edges, "seconds_links": t_links,
        "seconds_merge": t_merge, "localize_merged": loc_merged, "localize_single": loc_single,
        "T_B_A_true": T_B_A.tolist(), "queries": args.queries, "config": args.config,
    })


if __name__ == "__main__":
    main()
