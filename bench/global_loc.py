"""Global localization from no prior on the 7-Scenes query pass, with failure analysis.

For each query frame (default 500:1000:10), runs `VisualLocalizer.localize_global` alone
(no prior, no state machine) against a map and reports: success (accepted) %, errors of
accepted poses (median, max, count > 0.5 m), VPR recall (the benchmark's reference node,
i.e. nearest keyframe facing the same way, among the top-k) and, for failures, why (VPR
miss vs verification/confirmation rejection) with the attempts' inlier counts.

    python bench/global_loc.py MAP [--frames 500:1000:10] [--config 7scenes] [--set K=V ...] [--name NAME]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import numpy as np
from _common import print_table, require_7scenes, write_json

from litevloc.base.frames import parse_frames
from litevloc.base.geometry import relative_pose_error
from litevloc.config import load_config
from litevloc.experiments.reloc import reference_node
from litevloc.pipelines.localization.vloc import VisualLocalizer
from litevloc.pipelines.topomap.io import load_map
from litevloc.runtime.sources import open_source
from litevloc.runtime.tools.posed import posed_frames
from litevloc.runtime.vloc_models import check_map_models, load_bundle, second_look_for


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("map", type=Path)
    ap.add_argument("--frames", default="500:1000:10")
    ap.add_argument("--config", default="7scenes")
    ap.add_argument("--set", dest="overrides", action="append", default=[])
    ap.add_argument("--name", default="global_loc")
    args = ap.parse_args()
    data = require_7scenes()
    cfg = load_config(args.config, args.overrides)
    bundle = load_bundle(cfg.models)
    topomap = check_map_models(load_map(args.map), bundle)
    loc = VisualLocalizer(topomap, cfg.localization, bundle.extract, bundle.describe, bundle.match,
                          second_look=second_look_for(topomap, cfg.models, cfg.localization, bundle))
    rows, failures, errs, times = [], [], [], []
    vpr_hit = 0
    src = open_source(data, parse_frames(args.frames), strict=True, rgbd_calibration=cfg.rgbd_calibration)
    for frame, T in posed_frames(src):
        if T is None:
            continue
        t0 = time.perf_counter()
        res = loc.localize_global(frame.t_ns, frame.color, frame.depth, frame.K)
        times.append(time.perf_counter() - t0)
        ref = reference_node(topomap, T, frame.depth, frame.K)
        tried = [a.node for a in res.attempts]
        vpr_hit += ref in tried
        if res.accepted and res.T_map_camera is not None:
            errs.append(relative_pose_error(res.T_map_camera, T))
        else:
            best = max(res.attempts, key=lambda a: a.inliers, default=None)
            failures.append({"frame": frame.index, "reason": res.reason, "ref_in_topk": ref in tried,
                             "best_inliers": best.inliers if best else 0,
                             "attempts": [f"{a.node}:{a.matches}m/{a.inliers}i:{a.reason}" for a in res.attempts]})
        rows.append(frame.index)
    n = len(rows)
    e = np.array(errs).reshape(-1, 2)
    summary = {
        "map": str(args.map), "frames": args.frames, "config": args.config, "overrides": args.overrides,
        "queries": n, "accepted": len(errs), "success_pct": 100.0 * len(errs) / max(n, 1),
        "vpr_ref_in_topk_pct": 100.0 * vpr_hit / max(n, 1),
        "median_m": float(np.median(e[:, 0])) if len(e) else float("nan"),
        "median_deg": float(np.median(e[:, 1])) if len(e) else float("nan"),
        "max_m": float(e[:, 0].max()) if len(e) else float("nan"),
        "max_deg": float(e[:, 1].max()) if len(e) else float("nan"),
        "wrong_over_0.5m": int(np.sum(e[:, 0] > 0.5)) if len(e) else 0,
        "within_25cm_5deg_pct": 100.0 * float(np.mean((e[:, 0] < 0.25) & (e[:, 1] < 5))) if len(e) else 0.0,
        "time_median_ms": 1e3 * float(np.median(times)), "failures": failures,
    }
    print_table(f"GL from no prior: {args.map} frames {args.frames}",
                ["queries", "success %", "VPR ref@k %", "med cm", "med deg", "max cm", "> 0.5 m", "ms/q"],
                [[n, summary["success_pct"], summary["vpr_ref_in_topk_pct"], 100 * summary["median_m"],
                  summary["median_deg"], 100 * summary["max_m"], summary["wrong_over_0.5m"],
                  summary["time_median_ms"]]])
    for f in failures:
        print(f"  frame {f['frame']}: {f['reason']} (ref in top-k: {f['ref_in_topk']}; {f['attempts'][:4]})")
    write_json(args.name, summary)


if __name__ == "__main__":
    main()
