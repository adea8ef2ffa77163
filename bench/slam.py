"""Maps from the robot's own sensors (issue 41): `map build --poses slam`, measured.

    .venv/bin/python bench/slam.py [--json PATH.json | NAME] [--cases office floor loop bland 7s 7s-camera]
        [--inject] [--queries] [--navigation] [--loop-query] [--placement] [--no-build] [--config default]

Cases (each `map build` runs in its own process: its peak RSS and seconds are its own):

* simulator mapping passes with their drifting odometry, seed 0: `sim:office|floor|bland?pass=map`,
  `sim:loop?pass=loop` (the passes `sim navigate` and `bench/loop.py` map with); the build's own
  report gives the errors against the simulator's ground truth (read after the build);
* `7s`: 7-Scenes redkitchen frames 0-499, `litevloc convert` drift odometry (seed 0), the
  ground-truth channel removed before the build; errors against the dataset's ground truth
  and against the SfM pseudo ground truth (similarity alignment: its own scale);
* `7s-camera`: the same with `--odometry-rate 0` (camera only);
* `--inject`: 10 % wrong loop factors (places more than 3 m apart) added to the office and loop
  graphs, re-optimised: how far the keyframes move (experiments/slam.py);
* `--queries`: 7-Scenes frames 500-999 localized (bench/accuracy.py, `joint`) against each 7-Scenes
  SLAM map moved into the ground truth's frame (SE(3) over its keyframes) and against the
  ground-truth-posed map;
* `--navigation`: office, floor: `litevloc sim navigate WORLD --localization litevloc` on the
  case's SLAM map (its build, moved into the world frame) and on the same mapping pass posed by
  ground truth (built once); loop: bench/loop.py's query lap and its goal images along the route,
  on both maps. `--no-build` reuses the cases' builds (`--cases floor loop --navigation
  --no-build`; long: 10-40 min per map);
* `--loop-query`: the loop world's query lap through the runtime (bench/loop.py --skip-nav) on the
  SLAM map moved into the world frame and on the ground-truth-posed map;
* `--placement`: office, floor, loop: where the world's goal images and `--extra` (120) frames of
  its second pass are placed (bench/goal_placement.py) on the SLAM map, on the ground-truth-posed
  map of the same pass, and on a control: the mapping pass of seed 1 posed by ground truth. The
  images placed differently by the SLAM and ground-truth maps are counted beside those placed
  differently by the two ground-truth maps (`--cases floor --placement --no-build`; 5-8 min a world,
  quiet, with the seed-1 map's build).

Writes one object per case with `keyframe_ate_m`, `odometry_ate_m`, `rpe_per_m`, `loops_kept`,
`wrong_loops_kept`, `s_per_keyframe`, `peak_rss_mb` (and for the worlds with --navigation
`goals_reached_slam_map`, `goals_reached_gt_map`, `goals_total`; with --placement `goal_placement`:
per map `right`, `wrong`, `refused`, `keyframes`, and `differ_slam_vs_gt`, `differ_gt_vs_gt_seed1`).
Timings come from a shared 2-core machine unless stated.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

import numpy as np
from _common import OUT, ROOT, SEVEN_SCENES, json_path, litevloc, print_table, require_7scenes, write_json

from litevloc.config import load_config
from litevloc.experiments.slam import (
    MAPPING_PASSES,
    case_figures,
    graph_errors,
    inject_wrong_loops,
    mapping_pass_uri,
    sim_reference,
    without_ground_truth,
)

HERE = OUT / "slam"


def sim_case(world: str, config: str) -> dict[str, Any]:
    d = HERE / world
    js, npz = d / "build.json", d / "graph.npz"
    litevloc("map", "build", mapping_pass_uri(world), "-o", str(d / "map"), "--force",
             "--poses", "slam", "--json", str(js), "--slam-graph", str(npz), "--config", config)
    return case_figures(json.loads(js.read_text()), world)


def inject(world: str, config: str) -> dict[str, Any]:
    cfg = load_config(config)
    ref = sim_reference(mapping_pass_uri(world), cfg.sim)
    return inject_wrong_loops(HERE / world / "graph.npz", ref, cfg.slam, 0.1, 3.0, seed=0)


def _reference(rec: Path) -> dict[int, np.ndarray]:
    from litevloc.hw.streams.mcap_io import McapSource
    from litevloc.runtime.tools.posed import posed_frames

    return {f.index: T for f, T in posed_frames(McapSource(rec)) if T is not None}


def sevenscenes_case(name: str, rate: float, pgt: Path | None) -> dict[str, Any]:
    data = require_7scenes()
    d = HERE / name
    d.mkdir(parents=True, exist_ok=True)
    full, rec = d / "with-gt.mcap", d / "robot.mcap"
    if not full.is_file():
        litevloc("convert", str(data), str(full), "--frames", "0:500", "--odometry-rate", str(rate), "--seed", "0",
                 "--config", "7scenes")
    if not rec.is_file():
        without_ground_truth(full, rec)
    js, npz = d / "build.json", d / "graph.npz"
    litevloc("map", "build", str(rec), "-o", str(d / "map"), "--force", "--poses", "slam", "--json", str(js),
             "--slam-graph", str(npz), "--config", "7scenes")
    build = json.loads(js.read_text())
    out = case_figures(build)
    cfg = load_config("7scenes")
    ev = graph_errors(npz, _reference(full), cfg.slam.graph)
    out.update({k: ev[k] for k in ("keyframe_ate_m", "rpe_per_m", "wrong_loops_kept")})
    out["T_reference_map"] = ev["T_reference_map"]
    out["reference"] = "7-Scenes ground truth (colour camera, preset 7scenes), read from the dataset after the build"
    if pgt is not None:
        from pgt_agreement import read_pgt

        out["keyframe_ate_vs_sfm_pgt_m"] = graph_errors(npz, read_pgt(pgt, "seq-01"), cfg.slam.graph,
                                                        similarity=True)["keyframe_ate_m"]
    out["odometry_ate_m"] = _odometry_ate(full, npz) if rate > 0 else None
    return out


def _odometry_ate(rec: Path, npz: Path) -> float:
    """ATE of the recording's odometry alone at the SLAM keyframes (camera = base_link, 7scenes)."""
    from litevloc.base.geometry import interpolate_pose_at
    from litevloc.hw.messages import Odometry
    from litevloc.hw.streams.mcap_io import McapSource
    from litevloc.pipelines.evaluation.trajectory import ate
    from litevloc.runtime.tools.slam_build import load_graph

    odo = [(m.t_ns, m.T_odom_base) for m in McapSource(rec) if isinstance(m, Odometry)]
    t = np.array([o[0] for o in odo], np.int64)
    P = np.stack([o[1] for o in odo])
    g = load_graph(npz)
    ref = _reference(rec)
    T_bc = load_config("7scenes").fusion.T_base_camera()
    kfs = [k for k in g.keyframes if k.index in ref and t[0] <= k.t_ns <= t[-1]]
    est = np.stack([interpolate_pose_at(k.t_ns, t, P) @ T_bc for k in kfs])
    return float(ate(est, np.stack([ref[k.index] for k in kfs])).rmse)


def moved_map(src: Path, dst: Path, T: list[list[float]]) -> Path:
    """A copy of a map moved into the reference frame (rigidly, SE(3) over its keyframes)."""
    from litevloc.pipelines.topomap.io import load_map
    from litevloc.pipelines.topomap.map_save import save_map
    from litevloc.pipelines.topomap.merge import transform_map

    save_map(transform_map(load_map(src), np.asarray(T, np.float64)), dst, overwrite=True)
    return dst


def queries(name: str, T: list[list[float]]) -> dict[str, Any]:
    """7-Scenes query pass against the SLAM map (moved into the ground truth's frame) and the
    ground-truth-posed map (bench/accuracy.py, `joint`)."""
    # the folder's name keys bench/accuracy.py's model cache: one name per map
    slam_map = moved_map(HERE / name / "map", HERE / name / f"{name}-map-in-gt-frame", T)
    out = {}
    for tag, m in (("slam_map", slam_map), ("gt_map", HERE / "7s-gt-map")):
        r = subprocess.run([sys.executable, str(ROOT / "bench" / "accuracy.py"), "--map", str(m), "--configs", "joint",
                            "--name", f"slam_{name}_{tag}"])
        if r.returncode != 0:
            raise SystemExit(f"bench/accuracy.py failed on {m}")
        res = json.loads((OUT / f"slam_{name}_{tag}.json").read_text())["results"][0]
        out[tag] = {k: res[k] for k in ("within_5cm_5deg_pct", "within_2cm_2deg_pct", "accepted_pct", "median_cm",
                                        "wrong_over_0.5m")}
    return out


def gt_map(world: str, seed: int, config: str) -> Path:
    """The world's mapping pass with `seed` posed by ground truth (`map build --poses
    ground-truth`), built once under HERE."""
    d = HERE / (f"{world}-gt-map" if seed == 0 else f"{world}-gt-map-seed{seed}")
    if not (d / "manifest.json").is_file():
        litevloc("map", "build", mapping_pass_uri(world, seed), "-o", str(d), "--force", "--poses", "ground-truth",
                 "--config", config)
    return d


def placement(world: str, config: str, extra: int) -> dict[str, Any]:
    """Where the goal images land (bench/goal_placement.py: the world's goal images and `extra`
    frames of its second pass, right within `RIGHT_M` of the true pose, wrong, or refused) on three
    maps: the case's SLAM map (moved into the world frame), the same mapping pass posed by ground
    truth, and a control, the mapping pass of seed 1 posed by ground truth (the building mapped
    again). The images on which the SLAM and ground-truth maps differ are set beside those on
    which the two ground-truth maps differ: a goal near the refusal line (ambiguous, too few PnP
    inliers for a metric pose) flips with the map's keyframes, whatever posed them."""
    from goal_placement import RIGHT_M, goal_images, is_goal_place, place_images, placement_counts

    from litevloc.pipelines.topomap.io import load_map
    from litevloc.runtime.vloc_models import check_map_models, load_bundle

    build = HERE / world / "build.json"
    if not build.is_file():
        raise SystemExit(f"--placement {world}: no SLAM build in {HERE / world}; run --cases {world} first")
    T = json.loads(build.read_text())["slam"]["evaluation"]["T_reference_map"]
    maps = {"slam_map": moved_map(HERE / world / "map", HERE / f"{world}-map-in-world-frame", T),
            "gt_map": gt_map(world, 0, config), "gt_map_seed1": gt_map(world, 1, config)}
    cfg = load_config(config)
    bundle = load_bundle(cfg.models)
    items = goal_images(world, cfg, extra)
    per: dict[str, list[dict[str, Any]]] = {}
    out: dict[str, Any] = {"images": len(items), "right_m": RIGHT_M, "control": mapping_pass_uri(world, 1)}
    for tag, m in maps.items():
        topomap = check_map_models(load_map(m), bundle)
        recs = place_images(items, topomap, bundle, {"defaults": cfg.planner.goal}, RIGHT_M, f"{world} {tag}")
        per[tag] = recs["defaults"]
        missed = [r["image"] for r in per[tag] if is_goal_place(r) and r["outcome"] != "right"]
        out[tag] = {"keyframes": topomap.n_nodes, **placement_counts(per[tag]), "goal_places_not_right": missed}

    def differ(a: str, b: str) -> int:
        return sum(x["outcome"] != y["outcome"] for x, y in zip(per[a], per[b], strict=True))

    out.update({"differ_slam_vs_gt": differ("slam_map", "gt_map"),
                "differ_gt_vs_gt_seed1": differ("gt_map", "gt_map_seed1"),
                "differ_slam_vs_gt_seed1": differ("slam_map", "gt_map_seed1")})
    return out


def navigation(world: str, config: str) -> dict[str, Any]:
    """Image-goal navigation (`sim navigate --localization litevloc`) on the case's SLAM map, moved
    into the world frame (SE(3) over its keyframes, from its build report), and on the same mapping
    pass posed by ground truth: the same pass, so only the poses differ. Reuses the case's build."""
    build = HERE / world / "build.json"
    if not build.is_file():
        raise SystemExit(f"--navigation {world}: no SLAM build in {HERE / world}; run --cases {world} first")
    T = json.loads(build.read_text())["slam"]["evaluation"]["T_reference_map"]
    maps = {"slam": moved_map(HERE / world / "map", HERE / f"{world}-map-in-world-frame", T),
            "ground-truth": gt_map(world, 0, config)}
    out: dict[str, Any] = {}
    for poses, m in maps.items():
        js = HERE / f"nav-{world}-{poses}.json"
        subprocess.run([sys.executable, "-m", "litevloc.cli.main", "sim", "navigate", world, "--map", str(m),
                        "--out-dir", str(HERE / f"nav-{world}-{poses}"), "--localization", "litevloc", "--json",
                        str(js), "--config", config])
        out[poses] = json.loads(js.read_text())
    s, g = out["slam"], out["ground-truth"]
    from litevloc.runtime.tools.sim_navigation import goal_ratios

    return {"goals_reached_slam_map": s["goals_reached"], "goals_reached_gt_map": g["goals_reached"],
            "goals_total": s["goals_total"], "path_ratio_slam_vs_gt_map": goal_ratios(s["goals"], g["goals"]),
            "mapping_pass": mapping_pass_uri(world),
            "runs": {k: {kk: v[kk] for kk in ("goals_reached", "goals_total", "time_s", "path_length_m",
                                               "collisions")} for k, v in out.items()}}


def loop_query(T: list[list[float]], nav: bool) -> dict[str, Any]:
    """The loop's query lap through the runtime (bench/loop.py) on the SLAM map moved into the world
    frame and on the same pass posed by ground truth (bench/loop.py's own map, built once); with
    `nav`, also its navigation to goal images along the route, LiteVLoc localization on each map."""
    out: dict[str, Any] = {}
    goals: dict[str, list[dict[str, Any]]] = {}  # per map, bench/loop.py's per-goal records (for the ratios)
    for tag, d in (("slam_map", HERE / "loop-query"), ("gt_map", HERE / "loop-gt")):
        d.mkdir(parents=True, exist_ok=True)
        if tag == "slam_map":
            shutil.rmtree(d / "map", ignore_errors=True)
            moved_map(HERE / "loop" / "map", d / "map", T)
        js = d / "loop.json"
        cmd = [sys.executable, str(ROOT / "bench" / "loop.py"), "--out-dir", str(d), "--reuse-map", "--json", str(js)]
        r = subprocess.run(cmd + (["--no-baseline"] if nav else ["--skip-nav"]))
        if r.returncode != 0:
            raise SystemExit(f"bench/loop.py failed on {d / 'map'}")
        q = json.loads(js.read_text())
        out[tag] = {k: q[k] for k in ("vloc_ate_m", "fused_ate_m", "odometry_ate_m", "localized_fraction",
                                      "goals_reached", "goals_total")}
        if nav:
            goals[tag] = q["navigation"]["goals"]
            out[tag]["navigation"] = {k: q["navigation"][k] for k in ("goals_reached", "goals_total", "time_s",
                                                                       "path_length_m", "collisions")}
    if nav:
        from litevloc.runtime.tools.sim_navigation import goal_ratios

        out.update({"goals_reached_slam_map": out["slam_map"]["goals_reached"],
                    "goals_reached_gt_map": out["gt_map"]["goals_reached"], "goals_total": out["gt_map"]["goals_total"],
                    "path_ratio_slam_vs_gt_map": goal_ratios(goals["slam_map"], goals["gt_map"]),
                    "goals": "bench/loop.py's goal images along the mapping route"})
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cases", nargs="+", default=["office", "floor", "loop", "bland", "7s", "7s-camera"])
    ap.add_argument("--config", default="default")
    ap.add_argument("--inject", action="store_true")
    ap.add_argument("--queries", action="store_true")
    ap.add_argument("--navigation", action="store_true")
    ap.add_argument("--no-build", action="store_true", help="reuse the cases' earlier builds (their figures kept)")
    ap.add_argument("--loop-query", action="store_true")
    ap.add_argument("--placement", action="store_true")
    ap.add_argument("--extra", type=int, default=120, help="--placement: second-pass frames as more goal images")
    ap.add_argument("--pgt", type=Path, default=SEVEN_SCENES / "pgt-sfm-seq-01.txt")
    ap.add_argument("--json", default="slam", help="the JSON: a path ending in .json, or a name under out/bench/")
    args = ap.parse_args()
    prev = json_path(args.json)
    res: dict[str, Any] = json.loads(prev.read_text()) if prev.is_file() else {}  # cases not rerun are kept
    for c in [] if args.no_build else args.cases:
        if c in MAPPING_PASSES:
            res[c] = sim_case(c, args.config)
        elif c in ("7s", "7s-camera"):
            res[c] = sevenscenes_case(c, 100.0 if c == "7s" else 0.0, args.pgt if args.pgt.is_file() else None)
        else:
            raise SystemExit(f"unknown case {c}")
        write_json(args.json, res)
    if args.inject:
        for w in ("office", "loop"):
            if w in res and (HERE / w / "graph.npz").is_file():  # a case built now or in an earlier run
                res[w]["wrong_loop_injection"] = inject(w, args.config)
            write_json(args.json, res)
    if args.queries:
        if not (HERE / "7s-gt-map" / "manifest.json").is_file():
            litevloc("map", "build", str(require_7scenes()), "--frames", "0:500", "-o", str(HERE / "7s-gt-map"),
                     "--force", "--config", "7scenes", "--poses", "ground-truth")
        for c in ("7s", "7s-camera"):
            if c in res:
                res[c]["queries"] = queries(c, res[c]["T_reference_map"])
                write_json(args.json, res)
    if args.navigation:
        for w in [c for c in args.cases if c in ("office", "floor")]:
            res.setdefault(w, {}).update(navigation(w, args.config))
            write_json(args.json, res)
    if args.placement:
        for w in [c for c in args.cases if c in ("office", "floor", "loop")]:
            res.setdefault(w, {})["goal_placement"] = placement(w, args.config, args.extra)
            write_json(args.json, res)
    nav_loop = args.navigation and "loop" in args.cases
    if args.loop_query or nav_loop:
        build = HERE / "loop" / "build.json"
        if not build.is_file():
            raise SystemExit(f"no loop build at {build}: run with --cases loop (without --no-build) first")
        ev = json.loads(build.read_text())["slam"]["evaluation"]
        res.setdefault("loop", {})["query_lap"] = loop_query(ev["T_reference_map"], nav_loop)
        if nav_loop:
            res["loop"].update({k: res["loop"]["query_lap"][k] for k in (
                "goals_reached_slam_map", "goals_reached_gt_map", "goals_total", "path_ratio_slam_vs_gt_map")})
        write_json(args.json, res)
    rows = [[c, r.get("keyframe_ate_m"), r.get("odometry_ate_m"), r.get("rpe_per_m"), r.get("loops_kept"),
             r.get("wrong_loops_kept"), sum((r.get("loops_rejected_by_gate") or {}).values()), r.get("loops_tried"),
             r.get("loops_pregated"), r.get("s_per_keyframe"), r.get("cpu_s_per_keyframe"), r.get("peak_rss_mb"),
             (r.get("wrong_loop_injection") or {}).get("moved_max_m")]
            for c, r in res.items() if c != "meta"]
    print_table("map build --poses slam (shared 2-core machine)",
                ["case", "kf ATE m", "odom ATE m", "RPE m/m", "loops kept", "wrong kept", "gate rejects", "tried",
                 "pre-gated", "s/kf", "CPU-s/kf", "RSS MB", "10% wrong: moved m"], rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
