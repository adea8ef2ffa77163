"""Localization and navigation in a building that changed since it was mapped (`bench/change.py`).

Per building (`experiments.buildings.BuildingRun`: a generator's world file and a world seed):

1. **Map** of the building as generated (its mapping pass, `buildings.ensure_map`).
2. **Unchanged baseline**: GL from no prior (a fresh `VisualLocalizer` per frame, as the loop
   probe) on every `query_every`-th frame of the query pass (seed `QUERY_SEED`), and image-goal
   navigation (`buildings.building_goals`, `run_navigation`, LiteVLoc localization).
3. **Each case** (an axis and a level of `WorldChangeParams`, or the `months_later` mix fixed in
   `litevloc.base.params.world_change.MIXES`): the same figures in the changed building, goal
   images taken in it, against the unchanged map; then the map updated with one run through the
   changed building (its mapping pass, seed `SESSION_SEED`, every `session_every`-th frame;
   `update_from_session`, as `litevloc map update`) and the figures again.
4. **Update cycles**: the map updated again and again, cycle c with a session through the
   months-later building drawn with change seed c (a building that keeps changing), and GL on
   that building's query pass (held out: another route than the session's) after each.

A query frame is *covered* when a keyframe lies within 0.5 m and 30 deg of its ground truth
(`experiments.splits.COVER`); `gl_accepted_of_covered` is the share of covered frames GL
accepted, `wrong_over_0_5m` counts accepted poses more than 0.5 m off (covered or not). The
simulator's map frame is its world frame, so poses compare directly.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from litevloc.base.geometry import relative_pose_error
from litevloc.base.params.world_change import MIXES, WorldChangeParams
from litevloc.config.schema import LiteVLocConfig
from litevloc.experiments.buildings import BenchSettings as BuildingSettings
from litevloc.experiments.buildings import BuildingRun, building_goals, ensure_map, failure_class
from litevloc.experiments.splits import COVER, coverage
from litevloc.pipelines.localization.vloc import VisualLocalizer
from litevloc.pipelines.topomap.io import load_map
from litevloc.pipelines.topomap.map_save import save_map
from litevloc.pipelines.topomap.session import OncePerImage, SessionFrame, update_from_session
from litevloc.runtime.tools.sim_navigation import run_navigation
from litevloc.runtime.vloc_models import ModelBundle, check_map_models, second_look_for
from litevloc.sim.source import SimSequenceSource
from litevloc.sim.world import World, load_world

QUERY_SEED, SESSION_SEED = 1, 3
WRONG_M = 0.5
MONTHS_LATER = "months_later"
# the report's levels per axis (fixed before any result); `bench/change.py --levels` picks others
LEVELS: dict[str, tuple[float, ...]] = {"lighting": (0.5, 1.0), "furniture": (0.3, 0.6), "pictures": (0.3, 0.6),
                                        "people": (1, 2), "doors": (0.5, 1.0)}


@dataclass(frozen=True)
class Case:
    """One change: an axis and its level, or the months-later mix (axis `MONTHS_LATER`, level 1)."""

    axis: str
    level: float

    def params(self, seed: int = 0) -> WorldChangeParams:
        if self.axis == MONTHS_LATER:
            return dataclasses.replace(MIXES[MONTHS_LATER], seed=seed)
        value: Any = int(self.level) if self.axis == "people" else float(self.level)  # people: a count
        return dataclasses.replace(WorldChangeParams(seed=seed), **{self.axis: value})


@dataclass(frozen=True)
class ChangeSettings:
    """What one run measures and at what cost."""

    buildings: BuildingSettings = field(default_factory=lambda: BuildingSettings(out_dir=Path("out/bench/change")))
    query_every: int = 15  # every 15th query frame: 1 Hz of the 15 Hz camera
    query_duration_s: float | None = None  # the query pass's first seconds only (None: all of it)
    session_every: int = 5
    session_duration_s: float | None = None  # an update run's first seconds only (None: the whole mapping pass)
    cycles: int = 10
    navigate: bool = True


def changed_world(run: BuildingRun, params: WorldChangeParams) -> World:
    """The building of `run` changed by `params`."""
    return load_world(run.generator, seed=run.seed, change=params,
                      **({"appearance": run.appearance} if run.appearance else {}))


# ------------------------------------------------------------------ figures
def gl_figures(world: World, map_dir: Path, cfg: LiteVLocConfig, bundle: ModelBundle,
               settings: ChangeSettings) -> dict[str, Any]:
    """GL from no prior on the query pass of `world` against the map at `map_dir`: per-frame
    records and the summary (queries, covered, accepted among covered, wrong > 0.5 m)."""
    topomap = check_map_models(load_map(map_dir), bundle)
    look = second_look_for(topomap, cfg.models, cfg.localization, bundle)
    src = SimSequenceSource(world, "query", QUERY_SEED, settings.query_duration_s, cfg.sim)
    poses = src.camera_poses()
    frames: list[dict[str, Any]] = []
    for i in range(0, src.frame_count(), settings.query_every):
        f = src.frame(i)
        loc = VisualLocalizer(topomap, cfg.localization, bundle.extract, bundle.describe, bundle.match,
                              second_look=look)
        res = loc.localize_global(f.t_ns, f.color, f.depth, f.K)
        d, a = coverage(topomap, poses[i])
        rec: dict[str, Any] = {"frame": i, "covered": bool(((d <= COVER[0][0]) & (a <= COVER[0][1])).any()),
                               "accepted": bool(res.accepted), "reason": res.reason}
        if res.accepted and res.T_map_camera is not None:
            rec["error_m"], rec["error_deg"] = relative_pose_error(res.T_map_camera, poses[i])
        frames.append(rec)
    return {"summary": gl_summary(frames), "frames": frames}


def gl_summary(frames: list[dict[str, Any]]) -> dict[str, Any]:
    """Counts of per-frame GL records and the share accepted among covered (None: none covered)."""
    covered = [f for f in frames if f["covered"]]
    ok = sum(f["accepted"] for f in covered)
    return {"queries": len(frames), "covered": len(covered), "accepted_covered": ok,
            "accepted": sum(f["accepted"] for f in frames),
            "wrong_over_0_5m": sum(f["accepted"] and f.get("error_m", 0.0) > WRONG_M for f in frames),
            "gl_accepted_of_covered": round(ok / len(covered), 4) if covered else None}


def nav_figures(run: BuildingRun, world: World, map_dir: Path, cfg: LiteVLocConfig, bundle: ModelBundle,
                settings: ChangeSettings) -> dict[str, Any]:
    """Image-goal navigation in `world` with LiteVLoc localization on the map at `map_dir`, goal
    images taken in `world`: goals reached / total and why the others were not."""
    if not settings.navigate:
        return {"goals_reached": None, "goals_total": None, "failures": {}}
    b = settings.buildings
    start, goals, _other = building_goals(world, cfg, run.seed, b.max_goals)
    params = dataclasses.replace(cfg.sim_navigation, goal_timeout_s=b.goal_timeout_s, vloc_hz=b.vloc_hz)
    s = run_navigation(world, cfg, map_dir, goals, world.goal_places[start], "litevloc", params, bundle).summary()
    failures: dict[str, int] = {}
    for g in s["goals"]:
        if g["outcome"] != "reached":
            failures[failure_class(g)] = failures.get(failure_class(g), 0) + 1
    return {"goals_reached": s["goals_reached"], "goals_total": s["goals_total"], "failures": failures}


# ------------------------------------------------------------------ map update
def _session(world: World, cfg: LiteVLocConfig, every: int, duration_s: float | None) -> list[SessionFrame]:
    src = SimSequenceSource(world, "map", SESSION_SEED, duration_s, cfg.sim)
    poses = src.camera_poses()
    out = []
    for i in range(0, src.frame_count(), every):
        f = src.frame(i)
        out.append(SessionFrame(f.t_ns, i, f.color, f.depth, f.K, None, poses[i]))
    return out


def update_map(map_dir: Path, world: World, cfg: LiteVLocConfig, bundle: ModelBundle, out: Path,
               every: int, duration_s: float | None = None) -> dict[str, Any]:
    """`map_dir` updated with one mapping run through `world` (as `litevloc map update`), saved
    at `out` (the run's first `duration_s` seconds; None: all of it); the update's figures."""
    topomap = check_map_models(load_map(map_dir), bundle)
    extract, describe = OncePerImage(bundle.extract), OncePerImage(bundle.describe)
    loc = VisualLocalizer(topomap, cfg.localization, extract, describe, bundle.match,
                          second_look=second_look_for(topomap, cfg.models, cfg.localization, bundle))
    frames = _session(world, cfg, every, duration_s)

    def session() -> Iterator[SessionFrame]:
        return iter(frames)

    t0 = time.perf_counter()
    res = update_from_session(topomap, session, loc, extract, describe, bundle.match, cfg.mapping)
    save_map(res.new_map, out, overwrite=True, descriptor_bytes=cfg.mapping.descriptor_bytes)
    r = res.report
    return {"nodes_before": topomap.n_nodes, "nodes_after": res.new_map.n_nodes, "added": len(r.added),
            "retired": len(r.retired), "replaced": len(r.replaced), "replace_outcomes": r.replace_outcomes,
            "known_place": r.known, "new_place": r.new_place,
            "changed_place": r.changed_place, "unreliable": r.unreliable,
            "mapped_view_unmatched": r.mapped_view_unmatched, "frames": res.frames,
            "seconds": round(time.perf_counter() - t0, 1)}


# ------------------------------------------------------------------ one building
def _figures(run: BuildingRun, world: World, map_dir: Path, cfg: LiteVLocConfig, bundles: dict[str, ModelBundle],
             settings: ChangeSettings) -> dict[str, Any]:
    return {"gl": gl_figures(world, map_dir, cfg, bundles["nav"], settings),
            "nav": nav_figures(run, world, map_dir, cfg, bundles["nav"], settings)}


def run_building(run: BuildingRun, cases: list[Case], settings: ChangeSettings, cfg: LiteVLocConfig,
                 bundles: dict[str, ModelBundle], log: Callable[[str], None] = print) -> dict[str, Any]:
    """Baseline, every case before and after one update, and the update cycles of one building."""
    t0 = time.perf_counter()
    world = changed_world(run, WorldChangeParams())
    map_dir, map_rec = ensure_map(run, world, settings.buildings, cfg, bundles["build"])
    out = settings.buildings.out_dir / run.name
    rec: dict[str, Any] = {"building": run.name, "map": map_rec,
                           "unchanged": _figures(run, world, map_dir, cfg, bundles, settings), "cases": []}
    log(f"  {run.name}: unchanged {_line(rec['unchanged'])}")
    for case in cases:
        w = changed_world(run, case.params())
        before = _figures(run, w, map_dir, cfg, bundles, settings)
        upd_dir = out / f"map_{case.axis}_{case.level:g}"
        upd = update_map(map_dir, w, cfg, bundles["build"], upd_dir, settings.session_every,
                         settings.session_duration_s)
        after = _figures(run, w, upd_dir, cfg, bundles, settings)
        rec["cases"].append({"axis": case.axis, "level": case.level, "truth": w.change_truth.to_dict(),
                             "before": before, "update": upd, "after": after})
        log(f"  {run.name}: {case.axis}={case.level:g} {_line(before)}; after update {_line(after)}")
    rec["cycles"] = update_cycles(run, map_dir, map_rec["keyframes"], cfg, bundles, settings, out, log)
    rec["wall_s"] = round(time.perf_counter() - t0, 1)
    return rec


def update_cycles(run: BuildingRun, map_dir: Path, first_nodes: int, cfg: LiteVLocConfig,
                  bundles: dict[str, ModelBundle], settings: ChangeSettings, out: Path,
                  log: Callable[[str], None]) -> list[dict[str, Any]]:
    """`settings.cycles` updates in a row, cycle c through the months-later building of change seed c."""
    cycles, current = [], map_dir
    for c in range(1, settings.cycles + 1):
        w = changed_world(run, Case(MONTHS_LATER, 1.0).params(seed=c))
        nxt = out / f"map_cycle_{c}"
        upd = update_map(current, w, cfg, bundles["build"], nxt, settings.session_every,
                             settings.session_duration_s)
        gl = gl_figures(w, nxt, cfg, bundles["nav"], settings)
        cycles.append({"cycle": c, "nodes": upd["nodes_after"], "update": upd, "gl": gl["summary"],
                       "map_size_ratio": round(upd["nodes_after"] / first_nodes, 4)})
        log(f"  {run.name}: cycle {c}: {upd['nodes_after']} keyframes, GL "
            f"{gl['summary']['accepted_covered']}/{gl['summary']['covered']} covered")
        current = nxt
    return cycles


def _line(fig: dict[str, Any]) -> str:
    g, n = fig["gl"]["summary"], fig["nav"]
    return (f"GL {g['accepted_covered']}/{g['covered']} covered, {g['wrong_over_0_5m']} wrong; "
            f"goals {n['goals_reached']}/{n['goals_total']}")


# ------------------------------------------------------------------ the JSON contract
def _ratio(num: int, den: int) -> float | None:
    return round(num / den, 4) if den else None


def _sums(figs: list[dict[str, Any]]) -> dict[str, Any]:
    gl = [f["gl"]["summary"] for f in figs]
    nav = [f["nav"] for f in figs]
    reached = None if any(n["goals_reached"] is None for n in nav) else sum(n["goals_reached"] for n in nav)
    total = None if any(n["goals_total"] is None for n in nav) else sum(n["goals_total"] for n in nav)
    return {"gl_accepted_of_covered": _ratio(sum(g["accepted_covered"] for g in gl), sum(g["covered"] for g in gl)),
            "wrong_over_0_5m": sum(g["wrong_over_0_5m"] for g in gl), "goals_reached": reached,
            "goals_total": total}


def contract(buildings: list[dict[str, Any]]) -> dict[str, Any]:
    """`cases` and `update_cycles` over all buildings (see `bench/change.py`): shares pooled over
    the buildings' frames and goals; a cycle's map size ratios (to the map before any update, and to
    the map after the first cycle: once a session's path is in the map, what the later cycles add)
    are the buildings' means."""
    ok = [b for b in buildings if "error" not in b]
    base = _sums([b["unchanged"] for b in ok])
    keys = [(c["axis"], c["level"]) for c in ok[0]["cases"]] if ok else []
    cases = []
    for k, (axis, level) in enumerate(keys):
        row: dict[str, Any] = {"axis": axis, "level": level}
        for name, figs in (("", [b["cases"][k]["before"] for b in ok]),
                           ("after_update", [b["cases"][k]["after"] for b in ok])):
            s = _sums(figs)
            part = {**{key: s[key] for key in ("gl_accepted_of_covered", "wrong_over_0_5m", "goals_reached",
                                               "goals_total")},
                    "gl_accepted_of_covered_unchanged": base["gl_accepted_of_covered"],
                    "goals_reached_unchanged": base["goals_reached"]}
            if name:
                row[name] = part
            else:
                row.update(part)
        cases.append(row)
    n_cycles = min((len(b["cycles"]) for b in ok), default=0)
    cycles = []
    for c in range(n_cycles):
        gl = [b["cycles"][c]["gl"] for b in ok]
        cycles.append({"cycle": c + 1,
                       "map_size_ratio": round(float(np.mean([b["cycles"][c]["map_size_ratio"] for b in ok])), 4),
                       "map_size_ratio_to_first_update": round(float(np.mean(
                           [b["cycles"][c]["nodes"] / b["cycles"][0]["nodes"] for b in ok])), 4),
                       "gl_accepted_of_covered": _ratio(sum(g["accepted_covered"] for g in gl),
                                                        sum(g["covered"] for g in gl))})
    return {"cases": cases, "update_cycles": cycles}


def plot(result: dict[str, Any], path: Path) -> Path:
    """Per axis: GL accepted among covered frames and goals reached (share of the unchanged
    building's) against the change level (0: unchanged), before and after one map update; with
    update cycles, a last panel: the map's size (to the map before any update) and GL per cycle."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cases, cycles = result["cases"], result["update_cycles"]
    axes = list(dict.fromkeys(c["axis"] for c in cases))
    panels = len(axes) + bool(cycles)
    fig, ax = plt.subplots(1, panels, figsize=(max(3.0 * panels, 6.0), 3.6), squeeze=False)
    driven = any(c["goals_total"] is not None for c in cases)
    for a, name in zip(ax[0], axes, strict=False):
        rows = sorted((c for c in cases if c["axis"] == name), key=lambda c: c["level"])
        for key, label, style in (("gl_accepted_of_covered", "GL accepted / covered", "-o"),
                                  ("goals", "goals reached / unchanged", "-s")):
            if key == "goals" and not driven:  # a run without navigation (--no-nav) has no goal figures
                continue
            for part, suffix, alpha in ((None, "", 1.0), ("after_update", " (after update)", 0.5)):
                xs, ys = [0.0], [1.0 if key == "goals" else rows[0]["gl_accepted_of_covered_unchanged"]]
                for c in rows:
                    r = c if part is None else c[part]
                    y = (r["goals_reached"] / r["goals_reached_unchanged"]
                         if key == "goals" and r["goals_reached"] is not None and r["goals_reached_unchanged"]
                         else r.get(key) if key != "goals" else None)
                    xs.append(c["level"])
                    ys.append(np.nan if y is None else y)
                a.plot(xs, [np.nan if y is None else 100 * y for y in ys], style, alpha=alpha,
                       label=label + suffix, color="#2b7bba" if key != "goals" else "#d62728")
        a.set_title(name)
        a.set_xlabel("level" if name != "people" else "people in view")
        a.grid(alpha=0.3)
    for a in ax[0][: len(axes)]:
        a.set_ylim(0, 105)
    if axes:
        ax[0][0].set_ylabel("%")
        ax[0][len(axes) - 1].legend(fontsize=7, loc="lower left")
    if cycles:
        _plot_cycles(ax[0][-1], cycles)
    fig.suptitle("LiteVLoc in a changed building (map of the building as generated)", fontsize=10)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _plot_cycles(a: Any, cycles: list[dict[str, Any]]) -> None:
    """Map size ratios (left axis) and GL accepted among covered frames (right axis, %) per update cycle."""
    xs = [0] + [c["cycle"] for c in cycles]
    a.plot(xs, [1.0] + [c["map_size_ratio"] for c in cycles], "-o", color="#444444", label="map size / before updates")
    a.axhline(1.3, color="#444444", ls=":", lw=1, label="1.3x")
    a.set_xlabel("update cycle")
    a.set_ylabel("map size ratio")
    a.set_title("update cycles")
    a.grid(alpha=0.3)
    gl = a.twinx()
    gl.plot([c["cycle"] for c in cycles],
            [np.nan if c["gl_accepted_of_covered"] is None else 100 * c["gl_accepted_of_covered"] for c in cycles],
            "-s", color="#2b7bba", label="GL accepted / covered (%)")
    gl.set_ylim(0, 105)
    gl.set_ylabel("GL accepted / covered %")
    lines = a.get_legend_handles_labels()[0] + gl.get_legend_handles_labels()[0]
    a.legend(lines, [str(h.get_label()) for h in lines], fontsize=7, loc="lower right")
