"""7-Scenes localization accuracy: the issue-#16 table of the defaults.

Runs `VisualLocalizer.process` (the state machine of `litevloc localize`: GL at start-up and
when lost, LL from the last accepted pose) on every query frame (default 500:1000, all 500;
a frame without an accepted pose is a failure) for each configuration:

* `joint`    — the defaults: joint multi-keyframe refinement (`pipelines/localization/refine.py`),
               with the map's keypoint depth as 3D residuals (`localization.refine.map_depth`).

(The starting point of issue #16, the single-keyframe PnP pose with a separate confirmation, is
no longer in the code; its figures are in this file's git history.)

and prints: share of all query frames within [2 cm, 2 deg], [5 cm, 5 deg], [25 cm, 5 deg];
accepted share; median / max error of accepted poses; poses wrong by > 0.5 m; covariance
calibration (share of accepted poses whose error lies inside their own 95 % ellipsoid,
position and rotation 3-dof each, chi-square); LL latency median / p90.

Models run once per frame and pair: features, VPR descriptors and matches are cached under
out/cache/accuracy/ (npz, no pickle) with the time each model call took, so the
configurations share them and a cached call counts its recorded time in the latency
(latency = geometry measured now + the model time measured when it first ran). The map is
built if absent (out/maps/7s, frames 0-499, `--config 7scenes`).

    python bench/accuracy.py [--frames 500:1000] [--map out/maps/7s] [--configs joint]
        [--set K=V ...] [--name accuracy]
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

import numpy as np
from _common import ROOT, print_table, require_7scenes, write_json
from numpy.typing import NDArray

from litevloc.base.frames import parse_frames
from litevloc.base.geometry import backproject_pixels, project, relative_pose_error, so3_log
from litevloc.config import load_config
from litevloc.models.types import Features
from litevloc.pipelines.depth_lookup import depth_at
from litevloc.pipelines.evaluation.reloc import inside_95_ellipsoids
from litevloc.pipelines.localization.refine import keyframe_distance_m, viewpoint_angle_rad
from litevloc.pipelines.localization.results import MatchedPixels
from litevloc.pipelines.localization.vloc import VisualLocalizer
from litevloc.pipelines.topomap.io import load_map
from litevloc.pipelines.topomap.types import NodeFeatures
from litevloc.runtime.sources import open_source
from litevloc.runtime.tools.posed import posed_frames
from litevloc.runtime.vloc_models import check_map_models, load_bundle, second_look_for

CONFIGS: dict[str, list[str]] = {"joint": []}
PUBLISHED = [  # redkitchen, from the papers (dense scene-specific models), for reference only
    {"method": "DSAC* (RGB-D)", "median_cm": 1.9, "median_deg": 0.80, "within_5cm_5deg_pct": 92.4},
    {"method": "hloc SP+SG", "median_cm": 4.0, "median_deg": 1.38, "within_5cm_5deg_pct": 61.9},
]


class ModelCache:
    """Extraction, VPR and matching cached per query frame in out/cache/accuracy/<map>/."""

    def __init__(self, folder: Path, bundle: Any, topomap: Any) -> None:
        self.folder = folder
        folder.mkdir(parents=True, exist_ok=True)
        self.bundle = bundle
        self.node_of = {id(f): i for i, f in enumerate(topomap.features)}
        self.frame = -1
        self.data: dict[str, np.ndarray] = {}
        self.dirty = False
        self.recorded_ms = 0.0  # model time of cached calls in the current query

    def _path(self, frame: int) -> Path:
        return self.folder / f"frame_{frame:05d}.npz"

    def start(self, frame: int) -> None:
        self.flush()
        self.frame, self.recorded_ms = frame, 0.0
        p = self._path(frame)
        self.data = dict(np.load(p, allow_pickle=False)) if p.is_file() else {}

    def flush(self) -> None:
        if self.dirty and self.frame >= 0:
            np.savez(self._path(self.frame), **self.data)
        self.dirty = False

    def extract(self, color: np.ndarray) -> Features:
        if "kp" not in self.data:
            t0 = time.perf_counter()
            f = self.bundle.extract(color)
            self.data.update(kp=f.keypoints, desc=f.descriptors, score=f.scores,
                             size=np.array(f.image_size), extract_ms=np.array((time.perf_counter() - t0) * 1e3))
            self.dirty = True
        else:
            self.recorded_ms += float(self.data["extract_ms"])
        d = self.data
        return Features(d["kp"], d["desc"], d["score"], (int(d["size"][0]), int(d["size"][1])))

    def describe(self, color: np.ndarray) -> np.ndarray:
        if "vpr" not in self.data:
            t0 = time.perf_counter()
            v = self.bundle.describe(color)
            self.data.update(vpr=np.asarray(v, dtype=np.float32), vpr_ms=np.array((time.perf_counter() - t0) * 1e3))
            self.dirty = True
        else:
            self.recorded_ms += float(self.data["vpr_ms"])
        return self.data["vpr"]

    def match(self, live: Any, ref: Any) -> tuple[np.ndarray, np.ndarray]:
        node = self.node_of[id(ref)]
        key = f"m{node}"
        if key + "_l" not in self.data:
            t0 = time.perf_counter()
            a, b = self.bundle.match(live, ref)
            self.data.update({key + "_l": np.asarray(a, dtype=np.int64), key + "_r": np.asarray(b, dtype=np.int64),
                              key + "_ms": np.array((time.perf_counter() - t0) * 1e3)})
            self.dirty = True
        else:
            self.recorded_ms += float(self.data[key + "_ms"])
        return self.data[key + "_l"], self.data[key + "_r"]


def ensure_map(path: Path, data: Path, overrides: list[str]) -> None:
    if (path / "manifest.json").is_file():
        return
    from litevloc.runtime.tools.map_building import MapBuildRequest, build_map

    print(f"building the map {path} (frames 0-499, --config 7scenes {' '.join(overrides)}) ...")
    build_map(MapBuildRequest(src=data, output=path, frames="0:500", config="7scenes"),
              load_config("7scenes", overrides))


def map_of(name: str, args: argparse.Namespace) -> tuple[Path, list[str]]:
    """The map a configuration localizes in, and the calibration overrides it was built with."""
    return args.map, []


def run_config(name: str, overrides: list[str], args: argparse.Namespace, data: Path, cache: ModelCache,
               topomap: Any) -> dict[str, Any]:
    """`overrides`: the configuration's, including the calibration its map was built with."""
    cfg = load_config(args.config, overrides + args.overrides)
    # the second look's model calls are live (not in the cache)
    loc = VisualLocalizer(topomap, cfg.localization, cache.extract, cache.describe, cache.match,
                          second_look=second_look_for(topomap, cfg.models, cfg.localization, cache.bundle))
    src = open_source(data, parse_frames(args.frames), strict=True, rgbd_calibration=cfg.rgbd_calibration)
    rows: list[dict[str, Any]] = []
    t_start = time.perf_counter()
    for frame, T_gt in posed_frames(src):
        if T_gt is None:
            continue
        cache.start(frame.index)
        t0, c0 = time.perf_counter(), time.process_time()
        res = loc.process(frame.t_ns, frame.color, frame.depth, frame.K)
        lat = (time.perf_counter() - t0) * 1e3 + cache.recorded_ms
        # CPU time of the live part (geometry and the uncached second look; all threads of this process)
        cpu = (time.process_time() - c0) * 1e3
        row: dict[str, Any] = {"frame": frame.index, "mode": res.mode, "accepted": res.accepted,
                               "latency_ms": lat, "live_cpu_ms": cpu, "keyframes": len(res.keyframes),
                               "reason": res.reason, "timings_ms": dict(res.timings_ms),
                               "second_look": "second_look" in res.timings_ms}
        ok_att = [a for a in res.attempts if a.reason == "ok"]
        if res.accepted and ok_att:  # the accepted keyframe's PnP: matches and inliers
            row["primary_matches"], row["primary_inliers"] = ok_att[-1].matches, ok_att[-1].inliers
        if res.accepted and res.T_map_camera is not None:
            et, er = relative_pose_error(res.T_map_camera, T_gt)
            E = np.linalg.inv(res.T_map_camera) @ T_gt  # right perturbation: T_gt = T_est @ E
            row.update(err_m=et, err_deg=er, err_cam_m=E[:3, 3].tolist(), err_cam_rotvec=so3_log(E[:3, :3]).tolist(),
                       err_map_m=(T_gt[:3, 3] - res.T_map_camera[:3, 3]).tolist(), ref_node=res.ref_node,
                       keyframe_nodes=list(res.keyframes),
                       view_angle_deg=float(np.degrees(viewpoint_angle_rad(
                           res.T_map_camera, topomap.T_map_camera[list(res.keyframes or (res.ref_node,))]))),
                       keyframe_distance_m=keyframe_distance_m(
                           res.T_map_camera, topomap.T_map_camera[list(res.keyframes or (res.ref_node,))]))
            if res.matches is not None:
                row["gt_reproj_px"] = gt_reprojection_px(res.matches, frame.depth, frame.K, T_gt, topomap,
                                                         cfg.localization.depth)
            if res.covariance is not None:
                inside = inside_95_ellipsoids(res.T_map_camera, T_gt, res.covariance)
                row["in_ellipsoid_t"], row["in_ellipsoid_r"] = inside
                row["sigma_t_m"] = float(np.sqrt(np.trace(res.covariance[:3, :3]) / 3))
                row["covariance"] = res.covariance.tolist()
        rows.append(row)
        if len(rows) % 50 == 0:
            print(f"  {name}: {len(rows)} frames, {time.perf_counter() - t_start:.0f} s", flush=True)
    cache.flush()
    return summarize(name, overrides, rows)


def gt_reprojection_px(matches: MatchedPixels, depth: NDArray[np.float32] | None, K: NDArray[np.float64],
                       T_gt: NDArray[np.float64], topomap: Any, depth_params: Any) -> float:
    """Does the ground truth fit the images? Median reprojection error (px) into the reference
    keyframe, under the GROUND-TRUTH pose, of the live points (live depth) that the accepted
    pose explains within the PnP threshold (its inliers: <= 3 px under the estimate by
    construction); NaN without inliers with depth."""
    if depth is None or not np.any(matches.inlier):
        return float("nan")
    uv = np.asarray(matches.live_px, np.float64)[matches.inlier]
    z = depth_at(depth, uv, depth_params).astype(np.float64)
    ok = np.isfinite(z)
    if not ok.any():
        return float("nan")
    pts = backproject_pixels(K, uv[ok], z[ok])
    T = np.linalg.inv(topomap.T_map_camera[matches.keyframe]) @ T_gt
    with np.errstate(invalid="ignore", divide="ignore"):
        proj = project(topomap.K[matches.keyframe], pts @ T[:3, :3].T + T[:3, 3])
    err = np.linalg.norm(proj - np.asarray(matches.keyframe_px, np.float64)[matches.inlier][ok], axis=1)
    return float(np.median(err))


def summarize(name: str, overrides: list[str], rows: list[dict[str, Any]]) -> dict[str, Any]:
    n = len(rows)
    acc = [r for r in rows if r["accepted"]]
    et = np.array([r["err_m"] for r in acc])
    er = np.array([r["err_deg"] for r in acc])

    def within(m: float, deg: float) -> float:
        return 100.0 * float(np.sum((et <= m) & (er <= deg))) / max(n, 1)

    cal = [r for r in acc if "in_ellipsoid_t" in r]
    ll = [r["latency_ms"] for r in rows if r["mode"] == "local"]
    ll_cpu = [r["live_cpu_ms"] for r in rows if r["mode"] == "local"]
    looks = [r for r in rows if r["mode"] == "local" and r["second_look"]]
    gt = np.array([r.get("gt_reproj_px", np.nan) for r in acc], dtype=np.float64)
    return {
        "config": name, "overrides": overrides, "queries": n, "accepted_pct": 100.0 * len(acc) / max(n, 1),
        "within_2cm_2deg_pct": within(0.02, 2), "within_5cm_5deg_pct": within(0.05, 5),
        "within_25cm_5deg_pct": within(0.25, 5),
        "median_cm": 100 * float(np.median(et)) if len(et) else float("nan"),
        "median_deg": float(np.median(er)) if len(er) else float("nan"),
        "max_cm": 100 * float(et.max()) if len(et) else float("nan"),
        "max_deg": float(er.max()) if len(er) else float("nan"),
        "wrong_over_0.5m": int(np.sum(et > 0.5)),
        "calib_t_pct": 100.0 * float(np.mean([r["in_ellipsoid_t"] for r in cal])) if cal else float("nan"),
        "calib_r_pct": 100.0 * float(np.mean([r["in_ellipsoid_r"] for r in cal])) if cal else float("nan"),
        "ll_latency_median_ms": float(np.median(ll)) if ll else float("nan"),
        "ll_latency_p90_ms": float(np.percentile(ll, 90)) if ll else float("nan"),
        "ll_live_cpu_median_ms": float(np.median(ll_cpu)) if ll_cpu else float("nan"),
        "ll_live_cpu_p90_ms": float(np.percentile(ll_cpu, 90)) if ll_cpu else float("nan"),
        "ll_second_looks": len(looks), "ll_second_looks_accepted": sum(r["accepted"] for r in looks),
        # the ground truth's own fit to the images, on the accepted poses' inliers (median px)
        "gt_reproj_px_median": float(np.nanmedian(gt)) if np.isfinite(gt).any() else float("nan"),
        "frames": rows,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", default="500:1000")
    ap.add_argument("--map", type=Path, default=ROOT / "out" / "maps" / "7s")
    ap.add_argument("--configs", nargs="+", default=list(CONFIGS), choices=list(CONFIGS))
    ap.add_argument("--set", dest="overrides", action="append", default=[],
                    help="applied to every config and to a map this run builds (name a new --map when they "
                         "change the calibration or mapping)")
    ap.add_argument("--name", default="accuracy")
    ap.add_argument("--src", type=Path, default=None, help="another posed recording (default: 7-Scenes)")
    ap.add_argument("--config", default="7scenes", help="preset of --src (default 7scenes)")
    args = ap.parse_args()
    data = require_7scenes() if args.src is None else args.src
    maps = {c: map_of(c, args) for c in args.configs}
    for path, calibration in maps.values():
        if args.src is None:
            ensure_map(path, data, calibration + args.overrides)
        elif not (path / "manifest.json").is_file():
            raise SystemExit(f"no map at {path} (build one for {args.src} first)")
    cfg = load_config(args.config, args.overrides)
    bundle = load_bundle(cfg.models)
    results = []
    for c in args.configs:
        path, calibration = maps[c]
        topomap = check_map_models(load_map(path), bundle)
        # the map's feature store makes each node's features on access: fixed objects, so the
        # model cache can tell the node of a match from the object it is given
        # (kept as NodeFeatures with the map's keypoint depth, which plain feature objects drop)
        topomap = dataclasses.replace(topomap, features=[
            NodeFeatures(f.keypoints, f.descriptors, f.scores, f.image_size, topomap.keypoint_depth(k))
            for k, f in enumerate(topomap.features)])
        folder = path.name if args.src is None else f"{path.name}-{data.stem}"
        cache = ModelCache(ROOT / "out" / "cache" / "accuracy" / folder, bundle, topomap)
        results.append(run_config(c, CONFIGS[c] + calibration, args, data, cache, topomap))
    cols = ["within_2cm_2deg_pct", "within_5cm_5deg_pct", "within_25cm_5deg_pct", "accepted_pct", "median_cm",
            "median_deg", "max_cm", "wrong_over_0.5m", "calib_t_pct", "calib_r_pct", "ll_latency_median_ms",
            "ll_latency_p90_ms", "ll_live_cpu_median_ms", "ll_live_cpu_p90_ms", "ll_second_looks",
            "gt_reproj_px_median"]
    print_table(f"{data.name}, frames {args.frames}, map {args.map.name} (percentages of ALL query "
                "frames; median/max over accepted poses)",
                ["config", "2cm2d%", "5cm5d%", "25cm5d%", "acc%", "med cm", "med deg", "max cm", ">0.5m",
                 "cal t%", "cal r%", "LL med ms", "LL p90 ms", "LL cpu med", "LL cpu p90", "LL looks", "GT px"],
                [[r["config"]] + [r[c] for c in cols] for r in results])
    print_table("published (reference)", ["method", "median cm", "median deg", "5cm5d%"],
                [[p["method"], p["median_cm"], p["median_deg"], p["within_5cm_5deg_pct"]] for p in PUBLISHED])
    write_json(args.name, {"frames": args.frames, "map": str(args.map), "preset": args.config,
                           "overrides": args.overrides,
                           "results": results, "published": PUBLISHED,
                           "note": "latency on a shared 2-core machine; cached model calls count their recorded time"})


if __name__ == "__main__":
    main()
