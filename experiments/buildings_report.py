"""Figures of a `experiments.buildings` run: per building, per generator, per goal camera and
in total; the acceptance checks on the totals; the table rows and the distribution plot.

Definitions (all per goal image driven, both localizations on the same images):

* reached: the planner said reached and the robot stands within the success radius;
* refused: the planner placed the image nowhere (reason classes `buildings.refusal_class`);
* wrong: placed more than `buildings.WRONG_PLACEMENT_M` from where the image was taken;
* path / time ratio: LiteVLoc's sum over the goals both localizations reached divided by
  ground truth's sum over the same goals.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path
from typing import Any

from litevloc.base.figures import save_figure
from litevloc.experiments.buildings import WRONG_PLACEMENT_M, failure_class

MODES = ("litevloc", "ground-truth")
CAMERAS = ("robot", "hand")


def _wrong(g: dict[str, Any]) -> bool:
    e = g.get("placement_error_m")
    return g.get("placed_node") is not None and e is not None and e > WRONG_PLACEMENT_M


def _both(b: dict[str, Any]) -> list[tuple[dict[str, Any], dict[str, Any]]]:
    gt = {g["name"]: g for g in b["ground-truth"]["goals"]}
    return [(g, gt[g["name"]]) for g in b["litevloc"]["goals"] if g["name"] in gt]


def building_figures(b: dict[str, Any]) -> dict[str, Any]:
    """One building's figures (the keys of the JSON's `buildings[*].figures`)."""
    out: dict[str, Any] = {}
    for mode in MODES:
        goals, s = b[mode]["goals"], b[mode]["summary"]
        out[mode] = {
            "reached": sum(g["outcome"] == "reached" for g in goals), "goals": len(goals),
            "refused": sum(g["placed_node"] is None for g in goals),
            "wrong_placements": sum(_wrong(g) for g in goals),
            "failures": dict(Counter(failure_class(g) for g in goals if g["outcome"] != "reached")),
            "collisions": s["collisions"], "first_fix_s": s.get("first_pose_s"),
            "lost_max_s": s.get("lost_max_s", 0.0), "time_s": s["time_s"], "path_m": s["path_length_m"],
            "wall_s": s["wall_s"],
        }
    pairs = [(g, t) for g, t in _both(b) if g["outcome"] == "reached" and t["outcome"] == "reached"]
    out["both_reached"] = len(pairs)
    for key, field in (("path_ratio", "path_length_m"), ("time_ratio", "time_s")):
        den = sum(t[field] for _, t in pairs)
        out[key] = round(sum(g[field] for g, _ in pairs) / den, 3) if pairs and den > 0 else None
    out["sum_path_lv"] = sum(g["path_length_m"] for g, _ in pairs)
    out["sum_path_gt"] = sum(t["path_length_m"] for _, t in pairs)
    out["sum_time_lv"] = sum(g["time_s"] for g, _ in pairs)
    out["sum_time_gt"] = sum(t["time_s"] for _, t in pairs)
    out["by_camera"] = camera_figures([b])
    return out


def camera_figures(buildings: list[dict[str, Any]]) -> dict[str, Any]:
    """Per goal camera: driven goals reached with each localization, and placement of every
    image of that camera (driven or placed only): right / wrong / refused."""
    out: dict[str, Any] = {}
    for cam in CAMERAS:
        driven = [(g, t) for b in buildings for g, t in _both(b) if g["camera"] == cam]
        images = [g for b in buildings for g in b["litevloc"]["goals"] if g["camera"] == cam] + \
                 [g for b in buildings for g in b.get("other_set", []) if g["camera"] == cam]
        out[cam] = {"driven": len(driven), "reached_litevloc": sum(g["outcome"] == "reached" for g, _ in driven),
                    "reached_ground_truth": sum(t["outcome"] == "reached" for _, t in driven),
                    "images": len(images), "placed_right": sum(g["placed_node"] is not None and not _wrong(g)
                                                               for g in images),
                    "placed_wrong": sum(_wrong(g) for g in images),
                    "refused": sum(g["placed_node"] is None for g in images),
                    "refusals": dict(Counter(failure_class(g) for g in images if g["placed_node"] is None))}
    return out


def totals(buildings: list[dict[str, Any]]) -> dict[str, Any]:
    """Sums over buildings (those that ran; `errors` counts the others) and the acceptance checks."""
    ok = [b for b in buildings if "error" not in b]
    figs = [b["figures"] for b in ok]
    t: dict[str, Any] = {"buildings": len(ok), "errors": len(buildings) - len(ok)}
    for mode in MODES:
        f = [x[mode] for x in figs]
        t[mode] = {"reached": sum(x["reached"] for x in f), "goals": sum(x["goals"] for x in f),
                   "refused": sum(x["refused"] for x in f), "wrong_placements": sum(x["wrong_placements"] for x in f),
                   "collisions": sum(x["collisions"] for x in f),
                   "buildings_without_collision": sum(x["collisions"] == 0 for x in f),
                   "failures": dict(sum((Counter(x["failures"]) for x in f), Counter())),
                   "lost_max_s": max((x["lost_max_s"] or 0.0 for x in f), default=0.0),
                   "first_fix_s_max": max((x["first_fix_s"] for x in f if x["first_fix_s"] is not None), default=None),
                   "never_fixed": sum(x["first_fix_s"] is None for x in f)}
    for key, num, den in (("path_ratio", "sum_path_lv", "sum_path_gt"), ("time_ratio", "sum_time_lv", "sum_time_gt")):
        d = sum(x[den] for x in figs)
        t[key] = round(sum(x[num] for x in figs) / d, 3) if d > 0 else None
    t["by_camera"] = camera_figures(ok)
    t["map"] = {"free_space_coverage_min": min((b["map"]["free_space_coverage"] for b in ok), default=None),
                "rooms_not_entered": sum(len(b["map"]["rooms_not_entered"]) for b in ok),
                "unmapped_openings": sum(b["map"]["unmapped_openings"] for b in ok)}
    t["wall_s"] = round(sum(b.get("wall_s", 0.0) for b in buildings), 1)
    t["cpu_s"] = round(sum(b.get("cpu_s", 0.0) for b in buildings), 1)
    t["acceptance"] = acceptance(t)
    return t


def acceptance(t: dict[str, Any]) -> dict[str, Any]:
    """The acceptance checks on the totals: value and pass/fail each."""
    lv, gt = t["litevloc"], t["ground-truth"]
    share = lv["reached"] / lv["goals"] if lv["goals"] else 0.0
    vs_gt = lv["reached"] / gt["reached"] if gt["reached"] else 0.0
    clean = lv["buildings_without_collision"] / t["buildings"] if t["buildings"] else 0.0
    return {"reached_share": [round(share, 3), share >= 0.90],
            "reached_vs_ground_truth": [round(vs_gt, 3), vs_gt >= 0.98],
            "wrong_placements": [lv["wrong_placements"], lv["wrong_placements"] == 0],
            "buildings_without_collision": [round(clean, 3), clean >= 0.95],
            "lost_max_s": [lv["lost_max_s"], lv["lost_max_s"] <= 30.0]}


def table_rows(buildings: list[dict[str, Any]]) -> list[list[Any]]:
    """One row per building (see `bench/buildings.py` for the header)."""
    rows = []
    for b in buildings:
        if "error" in b:
            rows.append([b["building"], "error", b["error"][:70]] + [""] * 10)
            continue
        f, m = b["figures"], b["map"]
        lv, gt = f["litevloc"], f["ground-truth"]
        rows.append([b["building"], m["keyframes"], f"{100 * m['free_space_coverage']:.0f}", m["unmapped_openings"],
                     f"{lv['reached']}/{lv['goals']}", f"{gt['reached']}/{gt['goals']}", lv["refused"],
                     lv["wrong_placements"], f"{lv['collisions']}/{gt['collisions']}",
                     "-" if lv["first_fix_s"] is None else lv["first_fix_s"], lv["lost_max_s"],
                     "-" if f["path_ratio"] is None else f["path_ratio"], b["wall_s"]])
    return rows


def plot(buildings: list[dict[str, Any]], png: Path, title: str) -> Path:
    """Distribution over buildings: goals reached per building (LiteVLoc vs ground truth), why
    goals were not reached, free-space coverage, LiteVLoc / ground-truth path ratio."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ok = [b for b in buildings if "error" not in b]
    fig, ax = plt.subplots(2, 2, figsize=(12, 8), dpi=100)
    names = [b["building"] for b in ok]
    x = range(len(ok))
    for k, (mode, colour) in enumerate((("litevloc", "tab:blue"), ("ground-truth", "tab:orange"))):
        share = [b["figures"][mode]["reached"] / max(b["figures"][mode]["goals"], 1) for b in ok]
        ax[0, 0].bar([i + 0.4 * k for i in x], share, width=0.4, color=colour, label=mode)
    ax[0, 0].set_xticks([i + 0.2 for i in x], names, rotation=70, fontsize=7)
    ax[0, 0].set_ylabel("share of goals reached")
    ax[0, 0].legend(fontsize=8)
    fails: Counter[str] = Counter()
    for b in ok:
        fails.update(b["figures"]["litevloc"]["failures"])
    if fails:
        ax[0, 1].barh(list(fails), list(fails.values()), color="tab:red")
    ax[0, 1].set_title("LiteVLoc goals not reached, by reason", fontsize=9)
    ax[1, 0].bar(list(x), [100 * b["map"]["free_space_coverage"] for b in ok], color="tab:green")
    ax[1, 0].set_xticks(list(x), names, rotation=70, fontsize=7)
    ax[1, 0].set_ylabel("map's coverage of the free space (%)")
    ratios = [b["figures"]["path_ratio"] for b in ok if b["figures"]["path_ratio"] is not None]
    ax[1, 1].hist(ratios, bins=15, color="tab:purple")
    ax[1, 1].set_xlabel("path ratio LiteVLoc / ground truth (per building)")
    fig.suptitle(title, fontsize=10)
    return save_figure(fig, png)


def placement_totals(results: list[dict[str, Any]]) -> dict[str, Any]:
    """Placement-only runs: per variant and goal camera, images placed right / wrong / refused
    (with the refusal classes), summed over the buildings."""
    ok = [r for r in results if "error" not in r]
    out: dict[str, Any] = {}
    for variant in (ok[0]["variants"] if ok else {}):
        out[variant] = {}
        for cam in CAMERAS:
            recs = [g for r in ok for g in r["variants"][variant] if g["camera"] == cam]
            out[variant][cam] = {
                "images": len(recs), "right": sum(g["placed_node"] is not None and not _wrong(g) for g in recs),
                "wrong": sum(_wrong(g) for g in recs), "refused": sum(g["placed_node"] is None for g in recs),
                "refusals": dict(Counter(failure_class(g) for g in recs if g["placed_node"] is None))}
    return out
