"""Map building on the 7-Scenes mapping pass and retrieval recall on the query pass.

Builds the map from frames 0-499 with the `7scenes` preset (the fixed protocol), then
for query frames 500-999 (every `--step`-th) reports VPR recall@1/@5 against the map's
keyframes (correct = a retrieved node within 0.5 m and 30 deg of the query's true pose)
and the oracle bound (some node within those thresholds at all). Also: keyframes,
coverage, edges, storage split, build time per keyframe.

    python bench/mapping.py [--step 5] [--set mapping.keyframes.budget=40 ...]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import litevloc, print_table, require_7scenes, write_json

from litevloc.base.frames import parse_frames
from litevloc.config import load_config
from litevloc.experiments.mapping import vpr_recall
from litevloc.pipelines.topomap.io import load_map
from litevloc.runtime.sources import open_source
from litevloc.runtime.tools.posed import posed_frames
from litevloc.runtime.vloc_models import load_bundle


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--step", type=int, default=5)
    ap.add_argument("--set", dest="overrides", action="append", default=[])
    args = ap.parse_args()
    data = require_7scenes()
    with tempfile.TemporaryDirectory() as tmp:
        mp = Path(tmp) / "map"
        js = Path(tmp) / "build.json"
        sets = [a for o in args.overrides for a in ("--set", o)]
        t0 = time.perf_counter()
        litevloc("map", "build", str(data), "--frames", "0:500", "-o", str(mp), "--config", "7scenes",
                 "--json", str(js), *sets)
        build_s = time.perf_counter() - t0
        build = json.loads(js.read_text())
        m = load_map(mp)
    cfg = load_config("7scenes", args.overrides)
    vpr = load_bundle(cfg.models).vpr
    queries = ((f.color, T) for f, T in posed_frames(open_source(data, parse_frames(f"500:1000:{args.step}")))
               if T is not None)
    r = vpr_recall(m, vpr.describe, queries)
    rows = [
        ["keyframes", build["nodes"]], ["candidates (motion pre-filter)", build["candidates"]],
        ["coverage", f"{100 * build['coverage']:.1f} %"],
        ["covisibility / connectivity edges", f"{build['covisibility_edges']} / {build['connectivity_edges']}"],
        ["graph + descriptors", f"{(build['graph_bytes'] + build['descriptor_bytes']) / 1e3:.1f} KB"],
        ["cached features", f"{build['feature_bytes'] / 1e6:.2f} MB"],
        ["images", f"{build['image_bytes'] / 1e6:.2f} MB"],
        ["build time per keyframe", f"{build['seconds_per_keyframe']:.2f} s"],
        [f"VPR recall@1 ({vpr.name}, {r.queries} queries)", f"{100 * r.recall_at_1:.1f} %"],
        ["VPR recall@5", f"{100 * r.recall_at_5:.1f} %"],
        ["oracle (a node within 0.5 m / 30 deg)", f"{100 * r.oracle:.1f} %"],
    ]
    print_table("Map building, 7-Scenes redkitchen frames 0-499; queries 500-999", ["quantity", "value"], rows)
    write_json("mapping", {"build": build, "build_seconds_total": build_s, "queries": r.queries,
                           "recall_at_1": r.recall_at_1, "recall_at_5": r.recall_at_5, "oracle": r.oracle,
                           "vpr": vpr.name, "overrides": args.overrides})


if __name__ == "__main__":
    main()
