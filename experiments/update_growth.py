"""What each map update added, and whether the map had already seen it (issue #78 item 3): for a
series of maps (the one before any update, then each update's result), the keyframes each one
added and, per added keyframe, the share of its view the previous map's keyframes already saw:
the (ground-plane cell, heading bin) pairs of its keypoints lifted with their depth, as map
building counts coverage (`pipelines.topomap.update.map_view_keys`, the map update's own test), found among the pairs of
the previous map's keyframes. A share near 1 is a view the map had and no longer matched (an
appearance change), near 0 one it never had (a new place).

    .venv/bin/python -m litevloc.experiments.update_growth MAP_BEFORE MAP_AFTER_1 [MAP_AFTER_2 ...]
        [--json PATH]

e.g. `out/bench/change/office-10/map out/bench/change/office-10/map_cycle_*` after
`bench/change.py --cycles N`.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from litevloc.base.errors import LiteVLocError
from litevloc.base.params.mapping import KeyframeParams
from litevloc.pipelines.topomap.diff import node_identities
from litevloc.pipelines.topomap.io import load_map
from litevloc.pipelines.topomap.types import TopoMap
from litevloc.pipelines.topomap.update import keyframe_view_keys, map_view_keys


def added_nodes(before: TopoMap, after: TopoMap) -> list[int]:
    """Nodes of `after` that `before` does not hold, by keyframe image identity (`diff.node_identities`:
    cycles through the same path add frames of the same index and time, in another building state)."""
    old = set(node_identities(before))
    return [i for i, ident in enumerate(node_identities(after)) if ident not in old]


def seen_shares(before: TopoMap, after: TopoMap, params: KeyframeParams) -> dict[int, float]:
    """Per node `after` added: the share of its view's coverage keys among `before`'s (NaN: none)."""
    seen, ref = map_view_keys(before, params)
    out = {}
    for i in added_nodes(before, after):
        v = keyframe_view_keys(after, i, ref, params)
        out[i] = float(np.isin(v, seen).mean()) if len(v) else float("nan")
    return out


def growth(maps: list[Path], params: KeyframeParams | None = None) -> list[dict[str, Any]]:
    """One record per update in the series `maps` (before any update first)."""
    params = params or KeyframeParams()
    loaded = [load_map(m) for m in maps]
    rows = []
    for k in range(1, len(loaded)):
        before, after = loaded[k - 1], loaded[k]
        s = np.array(list(seen_shares(before, after, params).values()))
        ok = s[np.isfinite(s)]
        rows.append({"map": str(maps[k]), "keyframes_before": before.n_nodes, "keyframes": after.n_nodes,
                     "added": len(s), "removed": before.n_nodes + len(s) - after.n_nodes,
                     "seen_share_median": float(np.median(ok)) if len(ok) else None,
                     "added_seen_at_least_0_8": int((ok >= 0.8).sum()),
                     "added_seen_under_0_5": int((ok < 0.5).sum())})
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("maps", nargs="+", type=Path, help="the map before any update, then each update's")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    if len(args.maps) < 2:
        ap.error("give the map before the update and at least one updated map")
    try:
        rows = growth(args.maps)
    except LiteVLocError as exc:
        print(f"update_growth: {exc}", file=sys.stderr)
        return 2
    for r in rows:
        print(f"{r['map']}: {r['keyframes_before']} -> {r['keyframes']} keyframes, {r['added']} added, "
              f"{r['removed']} removed; views already seen: median {r['seen_share_median']}, "
              f">= 0.8 seen {r['added_seen_at_least_0_8']}, < 0.5 seen {r['added_seen_under_0_5']}")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
