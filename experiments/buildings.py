"""Image-goal navigation over many generated buildings (`bench/buildings.py`).

Per building (a generator's world file and a world seed; `--appearance aliased` gives the same
buildings with the first simulator's pictures):

1. **Map**: the simulated mapping pass (`pass=map`: into every room and along every corridor,
   looking around; `litevloc.sim.trajectory`) built into a map in this process as `map build
   sim:...` builds it (depth-only pass 1, colour for the keyframes only). Reported: keyframes,
   the map's own coverage figure, its coverage of the building's free space
   (`litevloc.sim.coverage`), rooms entered, and the unmapped openings of its occupancy grid
   (`pipelines.topomap.openings`).
2. **Goals**: the start room is the first room; the goal rooms are the others, at most
   `max_goals` of them (drawn with `default_rng([seed, 31])`, kept in room order: the floor's
   14 would triple its driving time), each photographed by the goal rule (`litevloc.sim.goals`);
   whether a room's driven image is the robot camera's or the hand-held one is drawn per room
   (the same stream, even odds), so both sets are driven in every building. The image of the
   other camera is placed too (placement only).
3. **Navigation**: the goal sequence driven twice from the start room's goal place, with
   LiteVLoc localization (`runtime.tools.sim_navigation.run_navigation`, as `litevloc sim navigate`)
   and with ground-truth localization, the same goal images, map and seeds.

A goal is *refused* when the planner placed it nowhere (its reason is kept), *wrong* when it
was placed more than `WRONG_PLACEMENT_M` from where its image was taken. Buildings run in
`workers` processes (models loaded once per process, one ONNX Runtime thread each).
"""

from __future__ import annotations

import dataclasses
import json
import multiprocessing
import time
from collections.abc import Callable, Iterable
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from litevloc.base.process_usage import cpu_seconds
from litevloc.config import load_config
from litevloc.config.schema import LiteVLocConfig
from litevloc.pipelines.topomap.build import MapBuilder
from litevloc.pipelines.topomap.io import load_map
from litevloc.pipelines.topomap.map_save import save_map
from litevloc.pipelines.topomap.openings import find_openings, openings_summary
from litevloc.runtime.planner.core import GoalPlanner, decode_goal_image, goal_locator
from litevloc.runtime.tools.sim_driver import Goal
from litevloc.runtime.tools.sim_navigation import NavRun, placed_position, render_goals, run_navigation
from litevloc.runtime.vloc_models import ModelBundle, load_bundle
from litevloc.sim.coverage import map_coverage
from litevloc.sim.source import SimSequenceSource
from litevloc.sim.world import World, load_world

GENERATORS = ("office", "floor", "bland")
WRONG_PLACEMENT_M = 2.0
REFUSAL_CLASSES = (("matches no map place", "no map place"), ("ambiguous", "ambiguous"),
                   ("only a flat patch", "flat patch only"),
                   ("only floor or ceiling tiles", "tiles only"), ("rejected", "bad image"),
                   ("behind a wall from its node", "place behind a wall"),
                   ("not reachable on the map's grid", "place unreachable"),
                   ("lies in an obstacle", "place in obstacle"),
                   ("pose lies inside an obstacle", "pose inside an obstacle"),
                   ("repeating texture fitted", "pose at keyframe unexplained"), ("no metric pose", "no metric pose"))


@dataclass(frozen=True)
class BuildingRun:
    """What to run: one generator, one world seed, optional appearance override."""

    generator: str
    seed: int
    appearance: str | None = None  # None: the world file's

    @property
    def name(self) -> str:
        return f"{Path(self.generator).stem}-{self.seed}" + (f"-{self.appearance}" if self.appearance else "")


@dataclass(frozen=True)
class BenchSettings:
    """Settings of one benchmark run (the defaults are the report's)."""

    config: str = "default"
    # `key=value` overrides of the configuration for every run (e.g. a baseline with a rule off)
    overrides: tuple[str, ...] = ()
    goal_timeout_s: float = 120.0
    vloc_hz: float = 1.0
    out_dir: Path = Path("out/bench/buildings")
    keep_maps: bool = True  # reuse a building's map when its folder holds one (same code, same seed)
    max_goals: int = 6  # goal rooms per building at most (drawn with the seed)
    # placement only (no driving): variant name -> `--set` overrides of the configuration, each
    # placing every room's robot and hand-held image; empty: map, place and drive
    placement_variants: tuple[tuple[str, tuple[str, ...]], ...] = ()


def load_building(run: BuildingRun) -> World:
    return load_world(run.generator, seed=run.seed, **({"appearance": run.appearance} if run.appearance else {}))


# ------------------------------------------------------------------ map
def build_map(world: World, cfg: LiteVLocConfig, bundle: ModelBundle, out: Path) -> dict[str, Any]:
    """The mapping pass of `world` built into a map at `out` (as `map build sim:...`); its build
    figures. Pass 1 renders depth for keyframe candidates only, pass 2 colour for keyframes."""
    t0, cpu0 = time.perf_counter(), cpu_seconds()
    src = SimSequenceSource(world, "map", 0, params=cfg.sim)
    builder = MapBuilder(cfg.mapping, bundle.extract, bundle.describe, bundle.match, bundle.extractor.name,
                         bundle.vpr.name)
    K, poses = src.params.intrinsics.K, src.camera_poses()
    for i, t in enumerate(src.frame_times):
        if builder.is_candidate(poses[i]):
            builder.add(int(t), None, src.depth(i), K, poses[i], i)
        else:
            builder.add_pose(poses[i], i)
    builder.select()
    for i, pos in sorted(builder.wanted().items()):
        f = src.frame(i)
        assert f.depth is not None
        builder.attach(pos, f.color, f.depth, None)
    topomap = builder.finish(selected=builder.select())
    r = builder.report
    topomap.meta.update({"source": f"sim:{world.spec.name}?pass=map&world_seed={world.spec.seed}",
                         "keyframe_coverage": f"{r.coverage:.4f}", "build_seconds": f"{time.perf_counter() - t0:.1f}"})
    save_map(topomap, out, overwrite=True, descriptor_bytes=cfg.mapping.descriptor_bytes)
    return {"keyframes": topomap.n_nodes, "frames": r.frames, "coverage": round(r.coverage, 4),
            "pass_s": round(src.duration_s, 1), "build_wall_s": round(time.perf_counter() - t0, 1),
            "build_cpu_s": round(cpu_seconds() - cpu0, 1)}


def map_report(world: World, map_dir: Path, radius: float) -> dict[str, Any]:
    """Coverage of the building's free space and the unmapped openings of the map's grid."""
    m = load_map(map_dir)
    openings = openings_summary(find_openings(m.grid))
    return {**map_coverage(world, m.grid, m.positions[:, :2], radius), "openings": openings,
            "unmapped_openings": len(openings)}


def ensure_map(run: BuildingRun, world: World, settings: BenchSettings, cfg: LiteVLocConfig,
               bundle: ModelBundle) -> tuple[Path, dict[str, Any]]:
    """The building's map folder (built, or kept from an earlier run when `keep_maps`) and its
    record: build figures, coverage of the free space, unmapped openings."""
    out = settings.out_dir / run.name
    map_dir = out / "map"
    if settings.keep_maps and (map_dir / "manifest.json").is_file() and (out / "map_build.json").is_file():
        rec = {**json.loads((out / "map_build.json").read_text()), "reused": True}
    else:
        rec = build_map(world, cfg, bundle, map_dir)
        (out / "map_build.json").write_text(json.dumps(rec))
    rec.update(map_report(world, map_dir, cfg.sim.robot_radius))
    return map_dir, rec


# ------------------------------------------------------------------ goals
def building_goals(world: World, cfg: LiteVLocConfig, seed: int,
                   max_goals: int) -> tuple[str, list[Goal], list[Goal]]:
    """(start room, the driven goals, the other camera's images of the same rooms)."""
    rooms = sorted(world.goal_places)
    start, rest = rooms[0], rooms[1:]
    rng = np.random.default_rng([seed, 31])
    if len(rest) > max_goals:
        rest = [rest[k] for k in sorted(rng.choice(len(rest), max_goals, replace=False))]
    hand = rng.random(len(rest)) < 0.5
    driven, other = [], []
    for name, h in zip(rest, hand, strict=True):
        sets = (render_goals(world, cfg, [name], camera="hand"), render_goals(world, cfg, [name], camera="robot"))
        driven += sets[0] if h else sets[1]
        other += sets[1] if h else sets[0]
    return start, driven, other


def refusal_class(reason: str) -> str:
    """A short name for why the planner refused a goal image."""
    return next((short for key, short in REFUSAL_CLASSES if key in reason), "other")


def failure_class(g: dict[str, Any]) -> str:
    """Why a goal was not reached: its refusal class, or what ended the drive."""
    if g["placed_node"] is None:
        return "refused: " + refusal_class(g["reason"])
    r = g["reason"]
    for key, short in (("never localized", "never localized"), ("no progress", "no progress"),
                       ("timeout", "timeout"), ("m from the true goal place", "stopped elsewhere"),
                       ("no path", "no path")):
        if key in r:
            return short
    return "other"


def place_other(goals: list[Goal], map_dir: Path, cfg: LiteVLocConfig, bundle: ModelBundle,
                extract: Callable[[Any], Any] | None = None,
                match: Callable[[Any, Any], Any] | None = None) -> list[dict[str, Any]]:
    """Where the planner puts each of `goals` (placement only, no driving); `extract`, `match`:
    the bundle's, or caching wrappers of them."""
    topomap = load_map(map_dir)
    locate = goal_locator(topomap, extract or bundle.extract, bundle.describe, match or bundle.match, cfg.planner)
    planner = GoalPlanner(topomap, locate, cfg.planner, cfg.fusion.T_base_camera())
    out = []
    for g in goals:
        res = planner.place(decode_goal_image(g.jpeg)).result
        p = placed_position(res, topomap)
        err = None if p is None or g.T_world_camera is None else float(np.linalg.norm(p[:2] - g.T_world_camera[:2, 3]))
        out.append({"name": g.name, "camera": g.camera, "placed_node": res.node, "reason": res.reason,
                    "placement_error_m": None if err is None else round(err, 3)})
    return out


# ------------------------------------------------------------------ one building
def _run_summary(run: NavRun) -> dict[str, Any]:
    s = run.summary()
    goals = s.pop("goals")
    s.pop("trace", None)
    keep = ("goals_reached", "goals_total", "time_s", "path_length_m", "collisions", "collision_xy", "wall_s",
            "first_pose_s", "search_legs", "lost_max_s", "lost_total_s", "localization_error_m")
    return {"summary": {k: s[k] for k in keep if k in s}, "goals": goals}


def run_building(run: BuildingRun, settings: BenchSettings, cfg: LiteVLocConfig, bundles: dict[str, ModelBundle],
                 log: Callable[[str], None] = print) -> dict[str, Any]:
    """Map, place and drive one building (module docstring); its JSON record."""
    t0, cpu0 = time.perf_counter(), cpu_seconds()
    world = load_building(run)
    map_dir, map_rec = ensure_map(run, world, settings, cfg, bundles["build"])
    rec: dict[str, Any] = {"building": run.name, "generator": run.generator, "seed": run.seed,
                           "appearance": world.spec.appearance, "world": world.summary(), "map": map_rec}
    m = rec["map"]
    log(f"  {run.name}: map {m['keyframes']} keyframes, free space {100 * m['free_space_coverage']:.0f} %, "
        f"{m['unmapped_openings']} unmapped openings")
    start, goals, other = building_goals(world, cfg, run.seed, settings.max_goals)
    rec["start"] = start
    params = dataclasses.replace(cfg.sim_navigation, goal_timeout_s=settings.goal_timeout_s, vloc_hz=settings.vloc_hz)
    for mode in ("litevloc", "ground-truth"):
        nav = run_navigation(world, cfg, map_dir, goals, world.goal_places[start], mode, params, bundles["nav"])
        rec[mode] = _run_summary(nav)
        s = rec[mode]["summary"]
        log(f"  {run.name}: {mode} {s['goals_reached']}/{s['goals_total']} ({s['wall_s']:.0f} s wall)")
    rec["other_set"] = place_other(other, map_dir, cfg, bundles["nav"])
    rec["wall_s"], rec["cpu_s"] = round(time.perf_counter() - t0, 1), round(cpu_seconds() - cpu0, 1)
    return rec


def placement_run(run: BuildingRun, settings: BenchSettings, cfgs: dict[str, LiteVLocConfig],
                  bundles: dict[str, ModelBundle], log: Callable[[str], None] = print) -> dict[str, Any]:
    """Placement only (no driving): the robot's and the hand-held image of every room placed under
    each configuration of `cfgs` (one match per image and keyframe, shared by the variants)."""
    t0 = time.perf_counter()
    world = load_building(run)
    cfg = next(iter(cfgs.values()))
    map_dir, map_rec = ensure_map(run, world, settings, cfg, bundles["build"])
    rooms = sorted(world.goal_places)
    goals = render_goals(world, cfg, rooms, camera="robot") + render_goals(world, cfg, rooms, camera="hand")
    cache: dict[tuple[int, int], Any] = {}

    def match(a: Any, b: Any) -> Any:
        key = (id(a), hash(np.asarray(b.keypoints).tobytes()))
        if key not in cache:
            cache[key] = bundles["nav"].match(a, b)
        return cache[key]

    feats: dict[int, Any] = {}
    extract = bundles["nav"].extract

    def extract_once(rgb: Any) -> Any:  # the same image: the same features object, so the cache hits
        key = hash(np.asarray(rgb).tobytes())
        if key not in feats:
            feats[key] = extract(rgb)
        return feats[key]

    variants = {name: place_other(goals, map_dir, c, bundles["nav"], extract_once, match) for name, c in cfgs.items()}
    log(f"  {run.name}: placed {len(goals)} images x {len(cfgs)} variants ({time.perf_counter() - t0:.0f} s)")
    return {"building": run.name, "generator": run.generator, "seed": run.seed, "map": map_rec,
            "variants": variants, "wall_s": round(time.perf_counter() - t0, 1)}


# ------------------------------------------------------------------ many buildings
_WORKER: dict[str, Any] = {}


def load_models(config: str, overrides: tuple[str, ...] = ()) -> tuple[LiteVLocConfig, dict[str, ModelBundle]]:
    """The configuration (one ONNX Runtime thread) and its model bundles: "nav" (localization,
    planner) and "build" (the mapping's covisibility matcher)."""
    cfg = load_config(config, overrides)
    models = dataclasses.replace(cfg.models, intra_op_threads=1)
    cfg = dataclasses.replace(cfg, models=models)
    return cfg, {"nav": load_bundle(models), "build": load_bundle(models, matcher=cfg.mapping.covisibility_matcher)}


def _init_worker(config: str, overrides: tuple[str, ...] = ()) -> None:
    cfg, bundles = load_models(config, overrides)
    _WORKER.update(cfg=cfg, bundles=bundles)


def _work(run: BuildingRun, settings: BenchSettings) -> dict[str, Any]:
    lines: list[str] = []
    try:
        if settings.placement_variants:
            models = _WORKER["cfg"].models
            cfgs = {name: dataclasses.replace(load_config(settings.config, [*settings.overrides, *sets]),
                                              models=models)
                    for name, sets in settings.placement_variants}
            rec = placement_run(run, settings, cfgs, _WORKER["bundles"], lines.append)
        else:
            rec = run_building(run, settings, _WORKER["cfg"], _WORKER["bundles"], lines.append)
    except Exception as exc:  # one building's failure is reported, the others go on
        rec = {"building": run.name, "generator": run.generator, "seed": run.seed,
               "error": f"{type(exc).__name__}: {exc}"}
    rec["log"] = lines
    return rec


def run_buildings(runs: Iterable[BuildingRun], settings: BenchSettings, workers: int = 2,
                  on_result: Callable[[dict[str, Any]], None] | None = None) -> list[dict[str, Any]]:
    """Every building of `runs` in `workers` processes; `on_result` is called as each finishes."""
    runs = list(runs)
    results: list[dict[str, Any]] = []
    ctx = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=_init_worker,
                             initargs=(settings.config, settings.overrides)) as pool:
        futures = [pool.submit(_work, r, settings) for r in runs]
        for fut in as_completed(futures):
            rec = fut.result()
            results.append(rec)
            if on_result is not None:
                on_result(rec)
    order = {r.name: k for k, r in enumerate(runs)}
    return sorted(results, key=lambda r: order.get(r["building"], 0))


def render_cost(runs: Iterable[BuildingRun], cfg: LiteVLocConfig, frames: int = 60) -> list[dict[str, Any]]:
    """Rendering cost per frame, the first simulator's buildings (`aliased`: its pictures, no
    clutter, no room-size jitter, goals in front of posters) against this generator's, the same
    seeds, in this process, frame by frame in turn (a busy machine slows both alike): median and
    p90 ms of colour + depth (`Renderer.render`) and median of depth alone (`render_depth`) over
    `frames` frames spread evenly along each building's mapping pass, and the seconds to
    generate and bake each building."""
    from litevloc.sim.render import Renderer

    legacy = {"appearance": "aliased", "goal_rule": "poster", "room_size_jitter": 0.0, "clutter_per_room": (0, 0)}
    out = []
    for run in runs:
        worlds: dict[str, Any] = {}
        for label, overrides in (("first simulator", legacy), ("varied", {})):
            t0 = time.perf_counter()
            world = load_world(run.generator, seed=run.seed, **overrides)
            ren = Renderer(world)
            src = SimSequenceSource(world, "map", 0, params=cfg.sim)
            poses = src.camera_poses()[np.linspace(0, src.frame_count() - 1, frames).astype(int)]
            worlds[label] = (world, ren, poses, time.perf_counter() - t0, [], [])
        for k in range(frames):
            for _world, ren, poses, _t, colour, depth in worlds.values():
                t1 = time.perf_counter()
                ren.render(poses[k], cfg.sim.intrinsics)
                t2 = time.perf_counter()
                ren.render_depth(poses[k], cfg.sim.intrinsics)
                colour.append(t2 - t1)
                depth.append(time.perf_counter() - t2)
        for label, (world, _ren, _poses, t_make, colour, depth) in worlds.items():
            out.append({"building": run.name, "world": label, "boxes": len(world.boxes),
                        "pictures": len(world.posters), "make_s": round(t_make, 2),
                        "render_ms_median": round(1e3 * float(np.median(colour)), 2),
                        "render_ms_p90": round(1e3 * float(np.percentile(colour, 90)), 2),
                        "depth_ms_median": round(1e3 * float(np.median(depth)), 2)})
    return out
