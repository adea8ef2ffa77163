"""`litevloc map diff OLD NEW`: nodes added / retired / moved and coverage, as a table and a PNG."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from litevloc.pipelines.topomap.diff import MapDiff, MapDiffError, coverage_raster, diff_maps
from litevloc.pipelines.topomap.io import load_map
from litevloc.pipelines.topomap.types import TopoMap
from litevloc.runtime.cli.common import add_config_args, add_json_arg, config_of, write_json
from litevloc.runtime.cli.main import UserError


def add_diff_parser(msub: argparse._SubParsersAction) -> None:
    d = msub.add_parser("diff", help="what changed between two versions of a map (table, PNG, JSON)")
    d.add_argument("old", type=Path, help="the earlier map folder")
    d.add_argument("new", type=Path, help="the later map folder")
    d.add_argument("-o", "--output", type=Path, help="PNG to write (top-down view of the changes)")
    add_config_args(d)
    add_json_arg(d)
    d.set_defaults(func=diff)


def diff(args: argparse.Namespace) -> int:
    params = config_of(args).mapping.diff
    old, new = load_map(args.old), load_map(args.new)
    try:
        d = diff_maps(old, new, params)
    except MapDiffError as exc:
        raise UserError(f"map diff {args.old} {args.new}: {exc}") from exc
    s = d.summary()
    rows = [
        ("nodes", f"{s['old_nodes']}", f"{s['new_nodes']}"),
        ("kept (same keyframe image)", "", f"{s['kept']}"),
        (f"  of which moved (> {params.moved_m} m or {params.moved_deg} deg)", "",
         f"{s['moved']} (max {s['moved_max_m']:.3f} m)"),
        ("retired", f"{s['retired']}", ""),
        ("added", "", f"{s['added']}"),
        ("observed floor area (m^2)", f"{s['coverage_old_m2']:.1f}", f"{s['coverage_new_m2']:.1f}"),
        ("  only in this map (m^2)", f"{s['coverage_only_old_m2']:.1f}", f"{s['coverage_only_new_m2']:.1f}"),
        ("keyframe places the other map also has", f"{100 * s['old_places_kept']:.0f} %",
         f"{100 * s['new_places_in_old']:.0f} %"),
    ]
    w = max(len(r[0]) for r in rows)
    print(f"{'':{w}}  {'OLD':>12}  {'NEW':>22}")
    for name, a, b in rows:
        print(f"{name:{w}}  {a:>12}  {b:>22}")
    for note in d.notes:
        print(f"note: {note}")
    if args.output is not None:
        print(f"wrote {plot_diff(old, new, d, args.output)}")
    write_json(args.json, {"old": str(args.old), "new": str(args.new), **s,
                           "retired_ids": d.retired.tolist(), "added_ids": d.added.tolist(),
                           "moved_ids": d.kept[d.moved].tolist() if len(d.moved) else []})
    return 0


def plot_diff(old: TopoMap, new: TopoMap, d: MapDiff, out_png: Path) -> Path:
    """Top-down view: both occupancy grids (observed only in OLD / NEW / both), kept nodes,
    retired (red crosses), added (green), moved (arrows from the old to the new position)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 8), dpi=110)
    labels, origin, res = coverage_raster(old.grid, new.grid)
    if labels.size:
        rgb = np.ones((*labels.shape, 3))
        rgb[labels == 1] = (0.96, 0.70, 0.70)  # observed only in OLD
        rgb[labels == 2] = (0.70, 0.90, 0.70)  # observed only in NEW
        rgb[labels == 3] = (0.82, 0.82, 0.82)  # both
        H, W = labels.shape
        ax.imshow(rgb, origin="lower", interpolation="nearest",
                  extent=(origin[0], origin[0] + W * res, origin[1], origin[1] + H * res))
    for colour, name in (((0.96, 0.70, 0.70), "floor seen only in OLD"), ((0.70, 0.90, 0.70), "only in NEW"),
                         ((0.82, 0.82, 0.82), "in both")):
        ax.fill_between([], [], color=colour, label=name)
    po, pn = old.grid.to_plane(old.positions), new.grid.to_plane(new.positions)
    kept_new = d.kept[:, 1] if len(d.kept) else np.zeros(0, np.int64)
    ax.scatter(pn[kept_new, 0], pn[kept_new, 1], s=14, color="tab:blue", label=f"kept ({len(d.kept)})", zorder=3)
    if len(d.retired):
        ax.scatter(po[d.retired, 0], po[d.retired, 1], s=30, marker="x", color="tab:red",
                   label=f"retired ({len(d.retired)})", zorder=4)
    if len(d.added):
        ax.scatter(pn[d.added, 0], pn[d.added, 1], s=22, color="tab:green", label=f"added ({len(d.added)})",
                   zorder=4)
    for k in d.moved:
        i, j = d.kept[k]
        ax.annotate("", xy=tuple(pn[j]), xytext=tuple(po[i]),
                    arrowprops={"arrowstyle": "->", "color": "tab:orange", "lw": 1.2})
    ax.plot([], [], color="tab:orange", label=f"moved ({len(d.moved)})")
    ax.set_aspect("equal")
    ax.set_xlabel("plane axis a (m)")
    ax.set_ylabel("plane axis b (m)")
    ax.set_title(f"map diff: {d.n_old} -> {d.n_new} keyframes")
    ax.legend(loc="upper right", fontsize=8)
    out_png.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(out_png)
    plt.close(fig)
    return out_png
