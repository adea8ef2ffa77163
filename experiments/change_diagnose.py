"""Where GL fails under one change axis, per query frame (issue #78 item 4): the rank of the first right
keyframe (within `RIGHT` of the truth) among the VPR candidates GL verified, what each verified candidate
gave (matches, inliers, refusal), and what the right keyframe alone gives when GL is told to verify it
(`only=`): place recognition failing vs verification failing. With `--update-every N`, against the
map after one update run through the changed building (every Nth frame, as `bench/change.py
--session-every`): what the update changed for each frame.

    .venv/bin/python -m litevloc.experiments.change_diagnose GENERATOR SEED [--every N] [--duration S]
        [--axes lighting=0.5 furniture=0.3 ...] [--update-every N] [--set KEY=VALUE ...] [--json PATH]

Tuning buildings only (never the report set, `bench/buildings.py`'s default seeds).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from litevloc.base.geometry import backproject_pixels, relative_pose_error
from litevloc.base.params.world_change import WorldChangeParams
from litevloc.experiments.buildings import BenchSettings, BuildingRun, ensure_map, load_models
from litevloc.experiments.change import MONTHS_LATER, QUERY_SEED, Case, changed_world, update_map
from litevloc.experiments.splits import COVER, coverage
from litevloc.pipelines.localization.checks.support import layer_share
from litevloc.pipelines.localization.results import LocalizationResult
from litevloc.pipelines.localization.vloc import VisualLocalizer
from litevloc.pipelines.topomap.io import load_map
from litevloc.pipelines.topomap.types import TopoMap
from litevloc.runtime.vloc_models import check_map_models, second_look_for
from litevloc.sim.source import SimSequenceSource

RIGHT = (1.0, 30.0)  # metres, degrees: a keyframe that views the query's place


def inlier_layers(topomap: TopoMap, res: LocalizationResult, depth: NDArray[np.float32] | None,
                  K: NDArray[np.float64]) -> tuple[int, float] | None:
    """How many of the accepted pose's inliers with its keyframe, lifted with the live depth (what
    the support check sees, less the matches only the map's depth explains), and which share of
    them lie on their two densest horizontal layers (`support.layer_share`); None without depth
    or matches."""
    m = res.matches
    if m is None or depth is None or res.T_map_camera is None:
        return None
    px = np.asarray(m.live_px, np.float64)[m.inlier]
    z = np.asarray(depth, np.float64)[px[:, 1].astype(int), px[:, 0].astype(int)]
    ok = np.isfinite(z) & (z > 0)
    if not ok.any():
        return None
    T = res.T_map_camera
    pts = backproject_pixels(K, px[ok], z[ok]) @ T[:3, :3].T + T[:3, 3]
    return len(pts), layer_share(pts @ np.asarray(topomap.grid.up, np.float64))


def diagnose(run: BuildingRun, case: Case | None, every: int, duration: float | None,
             overrides: tuple[str, ...], out_dir: Path, uncovered: bool = False,
             update_every: int = 0) -> dict[str, Any]:
    """Per-frame GL records of `run` changed by `case` (None: unchanged) against its unchanged map,
    or with `update_every` > 0 against that map after one update run through the changed building
    (every `update_every`-th frame of it); with `uncovered`, frames the map does not cover too
    (their accepted poses can be wrong as well)."""
    cfg, bundles = load_models("default", overrides)
    settings = BenchSettings(out_dir=out_dir)
    map_dir, _ = ensure_map(run, changed_world(run, WorldChangeParams()), settings, cfg, bundles["build"])
    world = changed_world(run, case.params() if case else WorldChangeParams())
    update: dict[str, Any] | None = None
    if update_every > 0:
        name = f"map_{case.axis}_{case.level:g}" if case else "map_unchanged"
        upd_dir = out_dir / run.name / f"{name}_update_every_{update_every}"
        record = upd_dir / "update.json"  # an update run kept from an earlier diagnosis of the same case
        if (upd_dir / "manifest.json").is_file() and record.is_file():
            update = {**json.loads(record.read_text()), "reused": True}
        else:
            update = update_map(map_dir, world, cfg, bundles["build"], upd_dir, update_every)
            record.write_text(json.dumps(update, default=str))
        print("UPDATE", json.dumps(update, default=str), flush=True)
        map_dir = upd_dir
    bundle = bundles["nav"]
    topomap = check_map_models(load_map(map_dir), bundle)
    look = second_look_for(topomap, cfg.models, cfg.localization, bundle)
    src = SimSequenceSource(world, "query", QUERY_SEED, duration, cfg.sim)
    poses = src.camera_poses()
    frames = []
    for i in range(0, src.frame_count(), every):
        f = src.frame(i)
        d, a = coverage(topomap, poses[i])
        covered = bool(((d <= COVER[0][0]) & (a <= COVER[0][1])).any())
        if not covered and not uncovered:
            continue
        right = [int(n) for n in np.argsort(d) if d[n] <= RIGHT[0] and a[n] <= RIGHT[1]]
        loc = VisualLocalizer(topomap, cfg.localization, bundle.extract, bundle.describe, bundle.match,
                              second_look=look)
        t0 = time.perf_counter()
        res = loc.localize_global(f.t_ns, f.color, f.depth, f.K)
        gl_ms = 1e3 * (time.perf_counter() - t0)
        cands = list(res.candidates)
        rank = next((k for k, n in enumerate(cands) if n in right), None)
        rec: dict[str, Any] = {"frame": i, "covered": covered, "accepted": bool(res.accepted), "reason": res.reason,
                               "stop": res.stop_reason, "gl_ms": gl_ms, "rank_right": rank, "n_right": len(right),
                               "gray_mean": float(np.mean(f.color)),
                               "attempts": [(a_.node, a_.matches, a_.inliers, a_.reason, a_.node in right)
                                            for a_ in res.attempts]}
        if res.accepted and res.T_map_camera is not None:
            rec["error_m"] = relative_pose_error(res.T_map_camera, poses[i])[0]
            kf_m, kf_deg = relative_pose_error(res.T_map_camera, topomap.T_map_camera[res.ref_node])
            rec["inliers_layer_share"] = inlier_layers(topomap, res, f.depth, f.K)
            rec.update(ref_node=res.ref_node, keyframes=list(res.keyframes), inliers=res.n_inliers,
                       second_look=res.second_look, from_keyframe_m=kf_m, from_keyframe_deg=kf_deg,
                       truth_from_keyframe_m=float(d[res.ref_node]), truth_from_keyframe_deg=float(a[res.ref_node]))
        if not res.accepted and right:
            loc2 = VisualLocalizer(topomap, cfg.localization, bundle.extract, bundle.describe, bundle.match,
                                   second_look=look)
            o = loc2.localize_global(f.t_ns, f.color, f.depth, f.K, only=right[:3])
            rec["oracle"] = {"accepted": bool(o.accepted), "reason": o.reason,
                             "attempts": [(a_.node, a_.matches, a_.inliers, a_.reason) for a_ in o.attempts]}
        frames.append(rec)
        print(json.dumps(rec, default=str), flush=True)
    cov = [r for r in frames if r["covered"]]
    wrong = sum(r["accepted"] and r.get("error_m", 0) > 0.5 for r in frames)
    summary = {"case": dataclasses.asdict(case) if case else None, "update": update, "covered": len(cov),
               "accepted": sum(r["accepted"] for r in cov), "queries": len(frames),
               "accepted_all": sum(r["accepted"] for r in frames), "wrong": wrong,
               "right_in_topk": sum(r["rank_right"] is not None for r in cov),
               "gl_ms_median": float(np.median([r["gl_ms"] for r in frames])) if frames else None}
    print("SUMMARY", json.dumps(summary), flush=True)
    return {"summary": summary, "frames": frames}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("generator")
    ap.add_argument("seed", type=int)
    ap.add_argument("--every", type=int, default=30)
    ap.add_argument("--duration", type=float, default=None)
    ap.add_argument("--axes", nargs="*", default=[], help="AXIS=LEVEL or months_later; none: unchanged")
    ap.add_argument("--uncovered", action="store_true", help="diagnose frames the map does not cover too")
    ap.add_argument("--update-every", type=int, default=0,
                    help="diagnose the map after one update run through the changed building, every Nth frame of it")
    ap.add_argument("--set", dest="overrides", action="append", default=[])
    ap.add_argument("--out-dir", type=Path, default=Path("out/bench/change_diag"))
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    run = BuildingRun(args.generator, args.seed)
    cases: list[Case | None] = [
        Case(MONTHS_LATER, 1.0) if s == MONTHS_LATER else Case(s.split("=")[0], float(s.split("=")[1]))
        for s in args.axes] or [None]
    out = [diagnose(run, c, args.every, args.duration, tuple(args.overrides), args.out_dir,
                    args.uncovered, args.update_every) for c in cases]
    if args.json:
        args.json.write_text(json.dumps(out, default=str))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
