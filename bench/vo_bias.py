"""The SLAM's visual edges against the simulator's truth (issue 41): does an edge measure the
motion long or short, over which points, and the depth disagreement that makes it so.

    .venv/bin/python bench/vo_bias.py [--worlds loop office] [--seed 1] [--step 0.3] [--pairs 40] [--realism]

Per world: `--pairs` frame pairs `--step` metres apart spread over the mapping pass (seed 1: a
tuning pass), each pair's edge as the front end makes it (experiments/vo_bias.py) over all matched
points, the floor's only and the rest, as its error along the true motion (median over the pairs;
gross errors, a texture repeating about one step along the path, counted apart); and, per surface
and range, how much nearer the nearer frame's lifted point of a matched feature lands in the
farther frame than that frame's own. Ideal images and depth unless --realism (the depth noise
then hides the bias in scatter). A few minutes; writes out/bench/vo_bias.json.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import print_table, write_json

from litevloc.base.geometry import invert
from litevloc.config import load_config
from litevloc.experiments.slam import MAPPING_PASSES, mapping_pass_uri
from litevloc.experiments.vo_bias import (
    FramePoints,
    depth_disagreement,
    edge_errors,
    edge_pairs,
    frame_points,
    summary,
)
from litevloc.pipelines.slam.frontend import FrontEnd
from litevloc.pipelines.slam.types import FrameImages
from litevloc.runtime.tools.slam_build import slam_models
from litevloc.runtime.vloc_models import load_bundle
from litevloc.sim.source import open_sim_source


def world_case(world: str, seed: int, step: float, pairs: int, realism: bool, overrides: list[str]) -> dict[str, Any]:
    cfg = load_config("default", overrides)
    if not realism:
        cfg = dataclasses.replace(cfg, sim=dataclasses.replace(
            cfg.sim, realism=dataclasses.replace(cfg.sim.realism, enabled=False)))
    src = open_sim_source(mapping_pass_uri(world, seed), cfg.sim)
    P = src.camera_poses()
    fe = FrontEnd(cfg.slam, cfg.mapping, cfg.localization, slam_models(cfg, load_bundle(cfg.models)),
                  cfg.fusion.T_base_camera())

    def points(i: int) -> FramePoints:
        f = src.frame(i)
        assert f.depth is not None
        return frame_points(fe, FrameImages(f.color, f.depth, None), f.K, P[i], i)

    errors, steps, disagreement = [], [], []
    for n, (i, j) in enumerate(edge_pairs(P, step, pairs), 1):
        T = invert(P[i]) @ P[j]  # T_i_j: frame j's camera in frame i's
        a, b = points(i), points(j)
        errors.append(edge_errors(fe, a, b, T))
        steps.append(float(np.linalg.norm(T[:3, 3])))
        disagreement.append(depth_disagreement(fe, a, b, T))
        if n % 10 == 0:
            print(f"  {world}: {n} pairs", flush=True)
    return {"world": world, "seed": seed, "realism": realism,
            **summary(errors, steps, np.concatenate(disagreement) if disagreement else np.zeros((0, 3)))}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--worlds", nargs="+", default=["loop", "office"], choices=sorted(MAPPING_PASSES))
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--step", type=float, default=0.3, help="metres between the frames of a pair (SLAM keyframes: 0.3)")
    ap.add_argument("--pairs", type=int, default=40)
    ap.add_argument("--realism", action="store_true", help="the simulator's noisy images and depth")
    ap.add_argument("--name", default="vo_bias")
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                    help="a configuration override (repeat for more)")
    args = ap.parse_args()
    cases = [world_case(w, args.seed, args.step, args.pairs, args.realism, args.overrides) for w in args.worlds]
    print_table("Visual edges: error along the true motion (median over pairs; + = measured long)",
                ["world", "pairs", "step m", "all mm", "all %", "all % per m", "floor %", "off-floor %",
                 "gross (all)"],
                [[c["world"], c["pairs"], c["step_median_m"], c["all"]["along_error_median_mm"],
                  c["all"]["along_error_median_pct"], c["all"]["along_error_per_m_pct"],
                  c["floor"]["along_error_median_pct"], c["off-floor"]["along_error_median_pct"], c["all"]["gross"]]
                 for c in cases])
    print_table("Depth disagreement of matched features (nearer frame's point in the farther frame; - = nearer)",
                ["world", "surface", "range m", "features", "median mm", "median %"],
                [[c["world"], r["surface"], f"{r['range_m'][0]:g}-{r['range_m'][1]:g}", r["features"],
                  r["median_mm"], r["median_pct"]] for c in cases for r in c["depth_disagreement"]])
    write_json(args.name, {"step_m": args.step, "overrides": args.overrides, "cases": cases})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
