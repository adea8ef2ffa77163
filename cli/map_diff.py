"""`litevloc map diff OLD NEW`: nodes added / retired / moved and coverage, as a table and a PNG."""

from __future__ import annotations

import argparse
from pathlib import Path

from litevloc.cli.common import add_config_args, add_json_arg, config_of
from litevloc.cli.main import UserError
from litevloc.pipelines.topomap.diff import MapDiffError, diff_maps
from litevloc.pipelines.topomap.io import load_map
from litevloc.pipelines.topomap.plot import plot_diff
from litevloc.runtime.tools.outputs import write_json


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
