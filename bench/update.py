"""Map update on real data (7-Scenes redkitchen): does a refreshed map localize better?

The map is built from the first half of the mapping pass (frames 0-249); `litevloc map
update` then adds the second half (frames 250-499, localized against the map, no ground
truth used) — keyframes where the place is new, retirements where the appearance no longer
matches. Both versions then localize the held-out query pass (frames 500-999, every 10th,
GL from no prior). Reported: nodes added/retired, update time, and accepted share and
median/max error with the old map vs the updated one; `map diff` of the two versions.

    python bench/update.py [--queries 500:1000:10] [--config 7scenes]

`--world office` runs the simulator case instead: the map of `office` (mapping pass), an
update session in `office-changed` (posters re-textured, furniture moved: its mapping pass
with another seed), and the changed world's query pass localized (`litevloc localize`, the
state machine) with the old and the updated map. `--world floor` does the same on the
15-room floor (`floor-changed`; recordings cached under out/update_sim/floor).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import OUT, ROOT, print_table, require_7scenes, write_json
from merge import build, localize_all

from litevloc.config import load_config
from litevloc.pipelines.topomap.io import load_map
from litevloc.runtime.vloc_models import check_map_models, load_bundle

MAPS = ROOT / "out" / "maps"


def sim_case(world: str, query_frames: str) -> None:
    """Old map vs updated map on a changed simulated world (see the module docstring)."""
    cli = [sys.executable, "-m", "litevloc.cli.main"]
    d = ROOT / "out" / "update_sim" / world
    d.mkdir(parents=True, exist_ok=True)
    changed = f"{world}-changed"
    recs = {"map": (world, "map", 0), "session": (changed, "map", 3), "query": (changed, "query", 5)}
    for name, (w, pas, seed) in recs.items():
        if not (d / f"{name}.mcap").is_file():
            print(f"recording {w} {pas} pass (seed {seed}) ...", flush=True)
            subprocess.run([*cli, "sim", "record", w, "--pass", pas, "--seed", str(seed), "-o",
                            str(d / f"{name}.mcap")], check=True)
    old = d / "map_old"
    if not (old / "manifest.json").is_file():
        subprocess.run([*cli, "map", "build", str(d / "map.mcap"), "-o", str(old), "--force"], check=True)
    new = d / "map_new"
    subprocess.run([*cli, "map", "update", str(old), str(d / "session.mcap"), "-o", str(new), "--force",
                    "--json", str(d / "update.json")], check=True)
    upd = json.loads((d / "update.json").read_text())
    subprocess.run([*cli, "map", "diff", str(old), str(new), "-o", str(OUT / f"update_{world}_diff.png")], check=True)
    loc = {}
    for name, m in (("old", old), ("new", new)):
        js = d / f"loc_{name}_{query_frames.replace(':', '_')}.json"
        if name == "old" and js.is_file() and js.stat().st_mtime > (old / "manifest.json").stat().st_mtime \
                and js.stat().st_mtime > (d / "query.mcap").stat().st_mtime:
            print(f"old map's localization cached in {js}", flush=True)  # same old map, same query frames
            loc[name] = json.loads(js.read_text())
            continue
        subprocess.run([*cli, "localize", str(m), str(d / "query.mcap"), "-o", str(d / f"traj_{name}.txt"),
                        "--frames", query_frames, "--json", str(js)], check=True)
        loc[name] = json.loads(js.read_text())
    keys = sorted(set(loc["old"]) & set(loc["new"]))
    rows = [[k, str(loc["old"][k]), str(loc["new"][k])] for k in keys if not isinstance(loc["old"][k], dict | list)]
    rows.insert(0, ["keyframes (+added / -retired)", str(upd["nodes_before"]),
                    f"{upd['nodes_after']} (+{upd['added']} / -{upd['retired']})"])
    print_table(f"map update, simulator: {world} map, updated with a {changed} session, {changed} query pass",
                ["what", "old map", "updated map"], rows)
    write_json(f"update_{world}", {"update": upd, "localize_old": loc["old"], "localize_new": loc["new"]})


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--queries", default="500:1000:10")
    ap.add_argument("--config", default="7scenes")
    ap.add_argument("--world", default=None, help="run the simulator case on WORLD and WORLD-changed instead")
    ap.add_argument("--sim-queries", default="0::5", help="simulator case: query-pass frames to localize (15 Hz "
                    "recording: every 5th is 3 Hz, the runtime's VLoc rate)")
    args = ap.parse_args()
    if args.world:
        sim_case(args.world, args.sim_queries)
        return
    data = require_7scenes()
    old = build(data, "0:250", MAPS / "update_old", args.config)
    new = MAPS / "update_new"
    OUT.mkdir(parents=True, exist_ok=True)
    js = OUT / "update_cli.json"
    cli = [sys.executable, "-m", "litevloc.cli.main"]
    subprocess.run([*cli, "map", "update", str(old), str(data), "--frames", "250:500", "-o", str(new), "--force",
                    "--config", args.config, "--json", str(js)], check=True)
    upd = json.loads(js.read_text())
    subprocess.run([*cli, "map", "diff", str(old), str(new), "-o", str(OUT / "update_diff.png"), "--json",
                    str(OUT / "update_diff.json")], check=True)
    cfg = load_config(args.config)
    bundle = load_bundle(cfg.models)
    loc_old = localize_all(check_map_models(load_map(old), bundle), bundle, args.config, data, args.queries)
    loc_new = localize_all(check_map_models(load_map(new), bundle), bundle, args.config, data, args.queries)
    rows = [
        ["keyframes", f"{upd['nodes_before']}", f"{upd['nodes_after']} (+{upd['added']} / -{upd['retired']})"],
        ["update session frames compared with the map", "",
         f"{upd['compared']}/{upd['frames']} in {upd['seconds']:.0f} s"],
        ["places known / new / changed / unreliable", "",
         f"{upd['known_place']} / {upd['new_place']} / {upd['changed_place']} / {upd['unreliable']}"],
        ["held-out GL accepted", f"{loc_old['accepted']}/{loc_old['queries']}",
         f"{loc_new['accepted']}/{loc_new['queries']}"],
        ["held-out GL median error", f"{loc_old['median_cm']:.2f} cm / {loc_old['median_deg']:.2f} deg",
         f"{loc_new['median_cm']:.2f} cm / {loc_new['median_deg']:.2f} deg"],
        ["held-out GL max error", f"{loc_old['max_cm']:.1f} cm", f"{loc_new['max_cm']:.1f} cm"],
    ]
    print_table("map update, 7-Scenes: map of frames 0-249, updated with frames 250-499",
                ["what", "old map", "updated map"], rows)
    write_json("update", {"update": upd, "localize_old": loc_old, "localize_new": loc_new,
                          "queries": args.queries, "config": args.config})


if __name__ == "__main__":
    main()
