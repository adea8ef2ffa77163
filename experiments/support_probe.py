"""GL from no prior at random free-space poses of a building: how many wrong poses (> 0.5 m) each
configuration accepts (issue #78 item 4: the check that the support rule's `min_height_m` may go).

The query passes of the benchmarks follow the mapping route, so the poses where floor or ceiling
tiles alone can verify a wrong place (a view at the floor, a turn between rooms) are rare in them.
This probe draws camera poses uniformly over the building's free space with a uniform heading,
renders each (the months-later building with `--months-later`) and runs GL from no prior once per
configuration: the default and each `--variant` (a list of `KEY=VALUE` overrides), on the same
frames, in the same process.

    .venv/bin/python -m litevloc.experiments.support_probe GENERATOR SEED [--poses N] [--months-later]
        [--variant KEY=VALUE ...] [--json PATH]

Tuning buildings only (never the report set, `bench/buildings.py`'s default seeds).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path
from typing import Any

import numpy as np

from litevloc.base.geometry import relative_pose_error
from litevloc.base.params.world_change import WorldChangeParams
from litevloc.config import load_config
from litevloc.config.schema import LiteVLocConfig
from litevloc.experiments.buildings import BenchSettings, BuildingRun, ensure_map, load_models
from litevloc.experiments.change import MONTHS_LATER, WRONG_M, Case, changed_world
from litevloc.experiments.splits import COVER, coverage
from litevloc.pipelines.localization.vloc import VisualLocalizer
from litevloc.pipelines.topomap.io import load_map
from litevloc.runtime.vloc_models import check_map_models, second_look_for
from litevloc.sim.realism import sample_lighting
from litevloc.sim.render import Renderer
from litevloc.sim.simulator import base_pose, camera_pose, render_frame
from litevloc.sim.world import World

PROBE_SEED = 41  # the random poses' seed (any fixed value; the probe's frames are its own)


def random_base_poses(world: World, n: int, seed: int, radius_m: float) -> list[np.ndarray]:
    """`n` base poses (4x4, world frame) uniform over the free space (`radius_m` clear of walls and
    furniture) with uniform headings."""
    rng = np.random.default_rng([seed, PROBE_SEED])
    x0, y0, x1, y1 = world.bounds
    out: list[np.ndarray] = []
    for _ in range(200 * n):
        if len(out) == n:
            break
        xy = rng.uniform((x0, y0), (x1, y1))
        if world.is_free(xy, radius_m):
            out.append(base_pose(float(xy[0]), float(xy[1]), float(rng.uniform(-np.pi, np.pi))))
    if len(out) < n:
        raise ValueError(f"found {len(out)} free poses of {n} in {200 * n} draws")
    return out


def probe(run: BuildingRun, n: int, months_later: bool, variants: dict[str, tuple[str, ...]],
          out_dir: Path) -> dict[str, Any]:
    """Per-pose GL records of each configuration in `variants` (name -> overrides) at `n` random
    poses of `run` (months later or unchanged) against its unchanged map; the summary per configuration."""
    base_cfg, bundles = load_models("default")
    map_dir, _ = ensure_map(run, changed_world(run, WorldChangeParams()), BenchSettings(out_dir=out_dir), base_cfg,
                            bundles["build"])
    world = changed_world(run, Case(MONTHS_LATER, 1.0).params() if months_later else WorldChangeParams())
    bundle = bundles["nav"]
    topomap = check_map_models(load_map(map_dir), bundle)
    cfgs: dict[str, LiteVLocConfig] = {
        name: dataclasses.replace(load_config("default", list(sets)), models=base_cfg.models)
        for name, sets in variants.items()}
    looks = {name: second_look_for(topomap, c.models, c.localization, bundle) for name, c in cfgs.items()}
    sim = base_cfg.sim
    ren = Renderer(world)
    light = sample_lighting(sim.realism, np.random.default_rng([run.seed, PROBE_SEED, 1]))
    frames = []
    for i, T_base in enumerate(random_base_poses(world, n, run.seed, sim.robot_radius)):
        T_cam = camera_pose(T_base, 0.0, 0.0, sim)
        f = render_frame(ren, T_cam, sim.intrinsics, sim.realism, light,
                         np.random.default_rng([run.seed, PROBE_SEED, 2, i]), i * 10**9, i)
        d, a = coverage(topomap, T_cam)
        rec: dict[str, Any] = {"pose": i, "xy": T_base[:2, 3].round(2).tolist(),
                               "covered": bool(((d <= COVER[0][0]) & (a <= COVER[0][1])).any())}
        for name, c in cfgs.items():
            loc = VisualLocalizer(topomap, c.localization, bundle.extract, bundle.describe, bundle.match,
                                  second_look=looks[name])
            res = loc.localize_global(f.t_ns, f.color, f.depth, f.K)
            r: dict[str, Any] = {"accepted": bool(res.accepted), "reason": res.reason}
            if res.accepted and res.T_map_camera is not None:
                r["error_m"], r["error_deg"] = relative_pose_error(res.T_map_camera, T_cam)
            rec[name] = r
        frames.append(rec)
        print(json.dumps(rec), flush=True)
    summary = {name: {"accepted": sum(r[name]["accepted"] for r in frames),
                      "accepted_covered": sum(r[name]["accepted"] for r in frames if r["covered"]),
                      "wrong_over_0_5m": sum(r[name]["accepted"] and r[name].get("error_m", 0.0) > WRONG_M
                                             for r in frames)}
               for name in cfgs}
    return {"building": run.name, "months_later": months_later, "poses": n,
            "covered": sum(r["covered"] for r in frames), "variants": {k: list(v) for k, v in variants.items()},
            "summary": summary, "frames": frames}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("generator")
    ap.add_argument("seed", type=int)
    ap.add_argument("--poses", type=int, default=100)
    ap.add_argument("--months-later", action="store_true", help="the months-later building (default: unchanged)")
    ap.add_argument("--variant", nargs="+", action="append", default=[], metavar="KEY=VALUE",
                    help="a configuration to compare with the default (repeatable)")
    ap.add_argument("--out-dir", type=Path, default=Path("out/bench/change_diag"))
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    variants = {"default": ()} | {" ".join(v): tuple(v) for v in args.variant}
    out = probe(BuildingRun(args.generator, args.seed), args.poses, args.months_later, variants, args.out_dir)
    print("SUMMARY", json.dumps(out["summary"]), flush=True)
    if args.json:
        args.json.write_text(json.dumps(out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
