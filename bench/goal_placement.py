"""Goal placement: where the planner puts goal images, right, wrong or refused, per world.

For each world, goal images with a known true camera pose are placed with
`pipelines.navigation.planner.localize_goal` (what `litevloc plan` and `sim navigate` run)
under the default parameters and under each `--alt-set` variant, in one run on the same
images, map and matches:

* the world's goal places (`sim navigate`'s goal images; on `loop`, `bench/loop.py`'s five
  images along the route), and
* `--extra N` frames of a second pass as more goal images (seed 1 of the world's query pass,
  `loop-lane` on the loop: another route, lighting and image noise than the mapping pass),
  drawn with a fixed seed.

Outcome per image: `right` (the goal pose within `--right-m` of the truth; a node-only
placement within 2x that of its keyframe), `wrong` (placed farther), `refused` (with the
reason's first words). Maps are `sim navigate`'s cached ones (out/navigate/WORLD/map;
out/bench/loop/map for the loop), built when absent. Prints a table per world and variant
and writes out/bench/goal_placement.json with every image's outcome and reason.

    python bench/goal_placement.py [--worlds office bland floor] [--extra 120]
        [--alt-set planner.goal.planar_rms_m=0 ...] [--maps-dir DIR --map-set KEY=VALUE ...]

`--maps-dir DIR` places the same images in the maps under DIR/WORLD/map (built there from the
same mapping pass with the `--map-set` overrides where absent): a mapping parameter against the
default maps, one run each.

Parameters are chosen on `office` and `bland` (the default worlds here); `floor` and `loop`
are reported on.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

import cv2
import numpy as np
from _common import ROOT, print_table, write_json
from numpy.typing import NDArray

OUTCOMES = ("right", "wrong", "refused")
RIGHT_M = 1.5  # a placement within this of the true goal pose is right (m)


def world_map(world: str, config: str, maps_dir: Path | None = None, map_set: tuple[str, ...] = ()) -> Path:
    """The cached map `sim navigate` (or `bench/loop.py`) uses for the world; built when absent.
    With `maps_dir`: the map under maps_dir/WORLD, built there with the `map_set` overrides."""
    from litevloc.runtime.tools.world_navigation import ensure_map

    if maps_dir is not None:
        return ensure_map(world, maps_dir / world, config, map_pass="loop" if world == "loop" else "map",
                          overrides=map_set)
    if world == "loop":
        return ensure_map("loop", ROOT / "out" / "bench" / "loop", config, map_pass="loop")
    return ensure_map(world, ROOT / "out" / "navigate" / world, config)


def goal_images(world_name: str, cfg: Any, extra: int) -> list[tuple[str, NDArray[np.uint8], NDArray[np.float64]]]:
    """(name, RGB image, true T_world_camera) of the world's goal images and `extra` frames of
    its second pass."""
    from litevloc.runtime.planner.core import decode_goal_image
    from litevloc.runtime.tools.sim_navigation import render_goals
    from litevloc.sim.realism import sample_lighting
    from litevloc.sim.render import Renderer
    from litevloc.sim.simulator import camera_pose, render_frame
    from litevloc.sim.source import SimSequenceSource
    from litevloc.sim.world import load_world

    world = load_world(world_name)
    if world_name == "loop":
        from loop import loop_goals

        goals = loop_goals(world, cfg, 5)[0]
    else:
        goals = render_goals(world, cfg, sorted(world.goal_places))
    items = [(g.name, decode_goal_image(g.jpeg), camera_pose(g.T_world_base, 0.0, 0.0, cfg.sim)) for g in goals]
    if extra:
        run = SimSequenceSource(world, "loop-lane" if world_name == "loop" else "query", 1, params=cfg.sim).run
        ren = Renderer(world)
        light = sample_lighting(cfg.sim.realism, np.random.default_rng([8, 11]))
        picks = np.sort(np.random.default_rng(5).choice(len(run.T_world_base), min(extra, len(run.T_world_base)),
                                                        replace=False))
        for j, i in enumerate(picks):
            T = camera_pose(run.T_world_base[i], 0.0, 0.0, cfg.sim)
            f = render_frame(ren, T, cfg.sim.intrinsics, cfg.sim.realism, light, np.random.default_rng([8, 19, j]),
                             0, j)
            ok, buf = cv2.imencode(".jpg", f.color[:, :, ::-1], [cv2.IMWRITE_JPEG_QUALITY, 90])
            assert ok
            items.append((f"frame_{int(i)}", decode_goal_image(buf.tobytes()), T))
    return items


def outcome(res: Any, topomap: Any, T_true: NDArray[np.float64], right_m: float) -> tuple[str, float | None]:
    """('right' | 'wrong' | 'refused', position error in metres or None)."""
    if res.node is None:
        return "refused", None
    if res.T_map_goal is not None:
        err = float(np.linalg.norm(res.T_map_goal[:3, 3] - T_true[:3, 3]))
        return ("right" if err <= right_m else "wrong"), err
    err = float(np.linalg.norm(topomap.T_map_camera[res.node][:3, 3] - T_true[:3, 3]))
    return ("right" if err <= 2 * right_m else "wrong"), err


def place_images(items: list[tuple[str, NDArray[np.uint8], NDArray[np.float64]]], topomap: Any, bundle: Any,
                 params: dict[str, Any], right_m: float, label: str) -> dict[str, list[dict[str, Any]]]:
    """Every image of `items` (`goal_images`) placed in `topomap` with `localize_goal` under each
    of `params` (variant name -> `GoalParams`), on the same features and matches: per variant, one
    record per image (outcome, error in metres, node, reason). Progress every 20 images."""
    from litevloc.pipelines.navigation.planner import localize_goal

    K = np.asarray(topomap.K[0], np.float64)
    per: dict[str, list[dict[str, Any]]] = {v: [] for v in params}
    t0 = time.perf_counter()
    for n, (name, rgb, T_true) in enumerate(items):
        feats, desc = bundle.extract(rgb), bundle.describe(rgb)
        cache: dict[int, Any] = {}

        def match(a: Any, b: Any, cache: dict[int, Any] = cache) -> Any:
            key = hash(np.asarray(b.keypoints).tobytes())  # a map node's features, decoded per access
            if key not in cache:
                cache[key] = bundle.match(a, b)
            return cache[key]

        for v, goal_params in params.items():
            res = localize_goal(feats, desc, K, topomap, match, goal_params)
            o, err = outcome(res, topomap, T_true, right_m)
            per[v].append({"image": name, "outcome": o, "error_m": err, "node": res.node, "reason": res.reason})
        if (n + 1) % 20 == 0:
            print(f"  {label}: {n + 1}/{len(items)} images ({time.perf_counter() - t0:.0f} s)", flush=True)
    return per


def is_goal_place(record: dict[str, Any]) -> bool:
    """Whether a `place_images` record is one of the world's goal places (not an extra frame_*)."""
    return not record["image"].startswith("frame_")


def placement_counts(records: list[dict[str, Any]]) -> dict[str, int]:
    """Outcome counts of `place_images` records, and how many of the world's goal places were
    placed right."""
    goals = [r for r in records if is_goal_place(r)]
    c = {o: sum(r["outcome"] == o for r in records) for o in OUTCOMES}
    c["goal_places_right"] = sum(r["outcome"] == "right" for r in goals)
    c["goal_places"] = len(goals)
    return c


def main() -> int:
    from litevloc.config import load_config
    from litevloc.pipelines.topomap.io import load_map
    from litevloc.runtime.vloc_models import check_map_models, load_bundle

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--worlds", nargs="+", default=["office", "bland"])
    ap.add_argument("--extra", type=int, default=120, help="second-pass frames per world as more goal images")
    ap.add_argument("--config", default="default")
    ap.add_argument("--alt-set", action="append", default=[], metavar="KEY=VALUE",
                    help="a variant compared with the defaults (one override each; repeat for more variants)")
    ap.add_argument("--right-m", type=float, default=RIGHT_M, help="a placement within this of the truth is right")
    ap.add_argument("--name", default="goal_placement")
    ap.add_argument("--maps-dir", type=Path, default=None,
                    help="use (and build where absent) the maps under DIR/WORLD instead of sim navigate's")
    ap.add_argument("--map-set", action="append", default=[], metavar="KEY=VALUE",
                    help="config override for the maps built under --maps-dir (e.g. mapping.keyframes.coverage=0.98)")
    args = ap.parse_args()
    if args.map_set and args.maps_dir is None:
        ap.error("--map-set needs --maps-dir (the default maps are sim navigate's)")

    alt = args.alt_set or ["planner.goal.planar_rms_m=0"]
    variants = {"defaults": load_config(args.config)}
    for kv in alt:
        variants[kv] = load_config(args.config, [kv])
    cfg = variants["defaults"]
    bundle = load_bundle(cfg.models)
    out: dict[str, Any] = {"variants": list(variants), "right_m": args.right_m, "worlds": {}}
    rows = []
    for world in args.worlds:
        topomap = check_map_models(load_map(world_map(world, args.config, args.maps_dir, tuple(args.map_set))), bundle)
        t0 = time.perf_counter()
        items = goal_images(world, cfg, args.extra)
        per = place_images(items, topomap, bundle, {v: c.planner.goal for v, c in variants.items()}, args.right_m,
                           world)
        counts = {v: placement_counts(recs) for v, recs in per.items()}
        for v, c in counts.items():
            rows.append([world, v, len(items), c["right"], c["wrong"], c["refused"],
                         f"{c['goal_places_right']}/{c['goal_places']}"])
        out["worlds"][world] = {"images": len(items), "counts": counts, "per_image": per,
                                "seconds": round(time.perf_counter() - t0, 1)}
    print_table(f"goal placement (right: within {args.right_m} m of the true goal pose)",
                ["world", "variant", "images", "right", "wrong", "refused", "goal places right"], rows)
    write_json(args.name, out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
