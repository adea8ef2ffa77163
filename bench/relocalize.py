"""Time to relocalize after tracking is lost, and what being LOST costs (issue #15 item 6).

`python bench/relocalize.py [--worlds office bland floor] [--json PATH]`; it also writes PATH
with .png: each VLoc call's wall time over sensor time, faults shaded.

Per world: a mapping pass is recorded and a map built (`litevloc sim record WORLD --pass
map`, `litevloc map build`, `--config default`; cached in out/reloc/), and a query pass
recorded (`--pass query --seed 7`: another route and lighting). The localizer
(`VisualLocalizer.process`, the default preset's models and parameters) runs over the
query pass at `--vloc-hz` of sensor time (1 Hz, as the runtime's sequential mode), and
the LL prior is the fused pose's stand-in: the last accepted VLoc pose carried on by the
ground-truth relative motion since (drift-free odometry; `--prior last`: the last VLoc pose
unmoved, what `process` uses without a prior). Tracking is forced LOST at several points,
alternating two faults:

* `blackout`: for `--blackout-s` (4 s) the camera gives black frames with invalid depth
  (a covered lens / camera dropout): LL fails until the localizer declares LOST;
* `jump`: a teleport-like odometry jump: from the event on, the prior handed to LL is the
  true pose moved `--jump-m` (3 m) sideways (the fused pose jumped), until GL relocalizes.

Per event it measures the sensor time from the fault's start and from the end of tracking
(->LOST, or TRACKING->GLOBAL when the prior is far from every node) to the next TRACKING
transition (a fault that starts while the localizer is not tracking is counted, not
timed), the same for every LOST episode of the run (forced or not), the GL attempts spent meanwhile (count, candidates
verified, wall ms) and the position error of the relocalized pose against ground truth.
Wall time per simulated second is compared while LOST (GL queries) and while TRACKING
(LL queries) in the same run. Prints tables, writes JSON (PATH, default
out/bench/relocalize.json; every query keeps its reason and each candidate's). The machine's
load average is recorded: wall times on a loaded machine are ratios within the run, not
absolute figures.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import ROOT, print_table

from litevloc.pipelines.localization.prior import Prior
from litevloc.pipelines.localization.tracking import TrackingState
from litevloc.pipelines.localization.vloc import VisualLocalizer

LOST_GRACE_S = 5.0  # a fault's loss of tracking comes within this many seconds of its end


def cli(*args: str) -> None:
    subprocess.run([str(Path(sys.executable).parent / "litevloc"), *args], check=True)


def prepare(world: str, out: Path, seed: int) -> tuple[Path, Path]:
    """(map folder, query recording), recorded and built when absent."""
    rec, mp, q = out / f"{world}-map.mcap", out / f"{world}-map", out / f"{world}-query-s{seed}.mcap"
    if not (mp / "manifest.json").is_file():  # the mapping pass is recorded only to build the map
        if not rec.is_file():
            cli("sim", "record", world, "-o", str(rec), "--pass", "map")
        cli("map", "build", str(rec), "-o", str(mp), "--config", "default", "--force")
    if not q.is_file():
        cli("sim", "record", world, "-o", str(q), "--pass", "query", "--seed", str(seed))
    return mp, q


def events_at(t0: float, t1: float, first_s: float, every_s: float) -> list[tuple[float, str]]:
    out, t, k = [], t0 + first_s, 0
    while t < t1 - every_s / 2:
        out.append((t, "blackout" if k % 2 == 0 else "jump"))
        t += every_s
        k += 1
    return out


def run_world(world: str, args: argparse.Namespace) -> dict[str, Any]:
    from litevloc.config import load_config
    from litevloc.pipelines.topomap.io import load_map
    from litevloc.runtime.sources import open_source
    from litevloc.runtime.tools.posed import posed_frames
    from litevloc.runtime.vloc_models import check_map_models, load_bundle, second_look_for

    mp, q = prepare(world, args.out, args.query_seed)
    cfg = load_config("default", args.overrides)
    bundle = load_bundle(cfg.models)
    topomap = check_map_models(load_map(mp), bundle)
    loc = VisualLocalizer(topomap, cfg.localization, bundle.extract, bundle.describe, bundle.match,
                          second_look=second_look_for(topomap, cfg.models, cfg.localization, bundle))
    src = open_source(q, strict=True)
    frames = []  # (t_s, frame, T_gt) at the VLoc rate
    next_t = None
    for frame, T_gt in posed_frames(src):
        t = frame.t_ns * 1e-9
        if next_t is None or t >= next_t:
            frames.append((t, frame, T_gt))
            next_t = t + 1.0 / args.vloc_hz
    t_start, t_end = frames[0][0], frames[-1][0]
    if args.max_s:
        frames = [f for f in frames if f[0] <= t_start + args.max_s]
        t_end = frames[-1][0]
    events = events_at(t_start, t_end, args.first_s, args.every_s)
    rng = np.random.default_rng(0)
    queries = []
    ev_i, active, jump_T = -1, None, None
    last_vloc: tuple[np.ndarray, np.ndarray] | None = None  # (accepted T_map_camera, T_gt at that frame)
    for t, frame, T_gt in frames:
        while ev_i + 1 < len(events) and t >= events[ev_i + 1][0]:
            ev_i += 1
            active = events[ev_i]
            if active[1] == "jump":
                a = rng.uniform(0, 2 * np.pi)
                jump_T = np.eye(4)
                jump_T[:3, 3] = args.jump_m * np.array([np.cos(a), np.sin(a), 0.0])  # horizontal, map frame
        color, depth, prior = frame.color, frame.depth, None
        if args.prior == "odometry" and last_vloc is not None and T_gt is not None:
            # the fused pose: the last accepted VLoc pose carried on by the motion since then
            prior = last_vloc[0] @ np.linalg.inv(last_vloc[1]) @ T_gt
        kind = None
        if active is not None and active[1] == "blackout" and t < active[0] + args.blackout_s:
            color = np.zeros_like(color)
            depth = np.full(color.shape[:2], np.nan, np.float32)
            kind = "blackout"
        if active is not None and active[1] == "jump" and jump_T is not None and T_gt is not None:
            # the fused pose jumped; odometry carries it on with the true motion
            prior = jump_T @ (T_gt if prior is None else prior)
            kind = "jump"
        state_before = loc.tracker.state
        n_tr = len(loc.tracker.transitions)
        w0 = time.perf_counter()
        res = loc.process(frame.t_ns, color, depth, frame.K, None if prior is None else Prior(prior))
        wall = time.perf_counter() - w0
        new = list(loc.tracker.transitions)[n_tr:] if len(loc.tracker.transitions) >= n_tr else []
        err = None
        if res.accepted and res.T_map_camera is not None and T_gt is not None:
            last_vloc = (res.T_map_camera, T_gt)
            err = float(np.linalg.norm(res.T_map_camera[:3, 3] - T_gt[:3, 3]))
        queries.append({"t": t, "mode": res.mode, "accepted": res.accepted, "wall_s": wall, "err_m": err,
                        "state_before": str(state_before), "state_after": str(loc.tracker.state), "fault": kind,
                        "attempts": len(res.attempts), "event": ev_i, "reason": res.reason,
                        "attempt_reasons": [f"{a.node}: {a.reason}" for a in res.attempts],
                        "transitions": [f"{x.from_state}->{x.to_state}" for x in new]})
        tracking = loc.tracker.state == TrackingState.TRACKING
        if active is not None and active[1] == "jump" and tracking and res.mode == "global":
            jump_T = None  # GL relocalized: the fused pose follows VLoc again
            active = None
    return summarise(world, events, queries, args, t_start, t_end, topomap.n_nodes)


def summarise(world: str, events: list[tuple[float, str]], queries: list[dict[str, Any]], args: argparse.Namespace,
              t_start: float, t_end: float, n_nodes: int) -> dict[str, Any]:
    per_event = []
    for k, (te, kind) in enumerate(events):
        qs = [x for x in queries if x["event"] == k]
        # tracking ends with ->LOST (LL failures) or TRACKING->GLOBAL (prior far from every node)
        fault_end = te + (args.blackout_s if kind == "blackout" else 0.0)
        tracking_at_fault = bool(qs) and qs[0]["state_before"] == "TRACKING"
        # the fault's own loss of tracking: within LOST_GRACE_S of its end (else a later, natural one)
        t_lost = next((x["t"] for x in qs if any(s.endswith("->LOST") or s == "TRACKING->GLOBAL"
                                                 for s in x["transitions"])), None)
        if not tracking_at_fault or (t_lost is not None and t_lost > fault_end + LOST_GRACE_S):
            t_lost = None
        t_back = None
        if t_lost is not None:
            t_back = next((x["t"] for x in qs if x["t"] >= t_lost and any(s.endswith("->TRACKING")
                                                                           for s in x["transitions"])), None)
        lost_q = [x for x in qs if t_lost is not None and x["t"] > t_lost and (t_back is None or x["t"] <= t_back)]
        reloc = next((x for x in qs if x["t"] == t_back), None)
        per_event.append({
            "kind": kind, "t_fault_s": te - t_start, "tracking_at_fault": tracking_at_fault,
            "went_lost": t_lost is not None,
            "t_lost_s": None if t_lost is None else t_lost - t_start,
            "lost_to_tracking_s": None if t_back is None or t_lost is None else t_back - t_lost,
            "fault_end_to_tracking_s": None if t_back is None else round(max(0.0, t_back - fault_end), 3),
            "gl_queries": len(lost_q), "gl_candidates_verified": sum(x["attempts"] for x in lost_q),
            "gl_wall_ms": [round(x["wall_s"] * 1e3, 1) for x in lost_q],
            "reloc_error_m": None if reloc is None else reloc["err_m"],
        })
    # every LOST episode of the run (forced or not): end of tracking -> next TRACKING
    episodes, t_out = [], None
    for x in queries:
        for tr in x["transitions"]:
            if t_out is None and (tr.endswith("->LOST") or tr == "TRACKING->GLOBAL"):
                t_out = x["t"]
            elif t_out is not None and tr.endswith("->TRACKING"):
                episodes.append({"t_lost_s": t_out - t_start, "lost_to_tracking_s": x["t"] - t_out,
                                 "reloc_error_m": x["err_m"]})
                t_out = None
    if t_out is not None:
        episodes.append({"t_lost_s": t_out - t_start, "lost_to_tracking_s": None, "reloc_error_m": None,
                         "still_lost_at_end_s": t_end - t_out})
    ep_t = [e["lost_to_tracking_s"] for e in episodes if e["lost_to_tracking_s"] is not None]
    # wall time per simulated second: queries at a fixed rate, so wall per query x rate
    first_track = next((i for i, x in enumerate(queries) if x["state_after"] == "TRACKING"), len(queries))
    after = queries[first_track + 1:]
    tracking = [x["wall_s"] for x in after if x["mode"] == "local" and x["fault"] is None]
    # GL queries on real images (black frames are answered in milliseconds: left out)
    lost = [x["wall_s"] for x in after if x["mode"] == "global" and x["fault"] != "blackout"]
    rate = args.vloc_hz
    ttr = [e["lost_to_tracking_s"] for e in per_event if e["lost_to_tracking_s"] is not None]
    errs = [x["err_m"] for x in queries if x["err_m"] is not None]
    return {
        "world": world, "nodes": n_nodes, "sensor_s": t_end - t_start, "vloc_hz": rate, "events": per_event,
        "events_total": len(per_event), "events_lost": sum(e["went_lost"] for e in per_event),
        "events_relocalized": len(ttr),
        "lost_to_tracking_median_s": float(np.median(ttr)) if ttr else None,
        "lost_to_tracking_max_s": float(np.max(ttr)) if ttr else None,
        "wall_per_sim_s_tracking": float(np.mean(tracking) * rate) if tracking else None,
        "wall_per_sim_s_lost": float(np.mean(lost) * rate) if lost else None,
        "lost_vs_tracking_wall_ratio": float(np.mean(lost) / np.mean(tracking)) if lost and tracking else None,
        "gl_query_wall_ms_median": float(np.median(lost) * 1e3) if lost else None,
        "gl_query_wall_ms_max": float(np.max(lost) * 1e3) if lost else None,
        "ll_query_wall_ms_median": float(np.median(tracking) * 1e3) if tracking else None,
        "episodes": episodes, "episodes_total": len(episodes),
        "episodes_median_s": float(np.median(ep_t)) if ep_t else None,
        "episodes_max_s": float(np.max(ep_t)) if ep_t else None,
        "episodes_unrecovered": sum(e["lost_to_tracking_s"] is None for e in episodes),
        "gl_candidates_per_query": float(np.mean([x["attempts"] for x in after if x["mode"] == "global"]))
        if any(x["mode"] == "global" for x in after) else None,
        "accepted_fraction": sum(x["accepted"] for x in queries) / max(1, len(queries)),
        "accepted_error_median_m": float(np.median(errs)) if errs else None,
        "accepted_error_max_m": float(np.max(errs)) if errs else None,
        "accepted_over_0_5m": sum(e > 0.5 for e in errs),
        "queries": queries,
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--worlds", nargs="+", default=["office", "bland", "floor"])
    ap.add_argument("--json", type=Path, default=ROOT / "out" / "bench" / "relocalize.json")
    ap.add_argument("--out", type=Path, default=ROOT / "out" / "reloc", help="recordings and maps (cached)")
    ap.add_argument("--vloc-hz", type=float, default=1.0)
    ap.add_argument("--first-s", type=float, default=15.0, help="first fault, s after the query pass starts")
    ap.add_argument("--every-s", type=float, default=20.0, help="seconds between faults")
    ap.add_argument("--blackout-s", type=float, default=4.0)
    ap.add_argument("--jump-m", type=float, default=3.0)
    ap.add_argument("--query-seed", type=int, default=7)
    ap.add_argument("--prior", choices=["odometry", "last"], default="odometry",
                    help="LL prior: the last accepted VLoc pose carried on by the true relative motion since "
                         "(drift-free odometry, as the fused pose) or the last VLoc pose as it is")
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                    help="config override for the query pass, e.g. --set localization.global_search.lost_cost_ratio=0")
    ap.add_argument("--max-s", type=float, default=0.0, help="use only the first S s of the query pass (0 = all)")
    ap.add_argument("--resummarise", type=Path, help="recompute the summaries of an earlier JSON (no localization)")
    args = ap.parse_args()
    if args.resummarise is not None:
        import json

        old = json.loads(args.resummarise.read_text())
        for k, v in old["params"].items():
            if k not in ("resummarise", "json"):
                setattr(args, k, Path(v) if k == "out" else v)
        results = []
        for r in old["worlds"]:
            qs = r["queries"]
            t0, t1 = qs[0]["t"], qs[-1]["t"]
            results.append(summarise(r["world"], events_at(t0, t1, args.first_s, args.every_s), qs, args, t0, t1,
                                     r["nodes"]))
        report(results, tuple(old["load_average_before"]), tuple(old["load_average_after"]), args)
        return 0
    if args.vloc_hz <= 0 or args.every_s <= args.blackout_s + 1:
        ap.error("--vloc-hz must be > 0 and --every-s longer than --blackout-s + 1")
    args.out.mkdir(parents=True, exist_ok=True)
    load0 = os.getloadavg()
    results = [run_world(w, args) for w in args.worlds]
    report(results, load0, os.getloadavg(), args)
    return 0


def report(results: list[dict[str, Any]], load0: tuple[float, ...], load1: tuple[float, ...],
           args: argparse.Namespace) -> None:
    for r in results:
        print_table(f"{r['world']}: {r['events_total']} faults over {r['sensor_s']:.0f} s of the query pass "
                    f"(VLoc at {r['vloc_hz']:g} Hz of sensor time, map {r['nodes']} nodes)",
                    ["t s", "fault", "LOST", "LOST->TRACKING s", "fault end->TRACKING s", "GL queries",
                     "candidates", "reloc err m"],
                    [[round(e["t_fault_s"]), e["kind"], "yes" if e["went_lost"] else "no",
                      "-" if e["lost_to_tracking_s"] is None else e["lost_to_tracking_s"],
                      "-" if e["fault_end_to_tracking_s"] is None else e["fault_end_to_tracking_s"],
                      e["gl_queries"], e["gl_candidates_verified"],
                      "-" if e["reloc_error_m"] is None else round(e["reloc_error_m"], 3)] for e in r["events"]])
    def fmt(v: Any) -> Any:
        return "-" if v is None else v

    print_table(f"summary (load average {load0[0]:.1f} -> {load1[0]:.1f} on {os.cpu_count()} CPUs)",
                ["world", "lost/faults", "relocalized", "median s", "max s", "all LOST episodes", "median s",
                 "max s", "unrecovered", "wall/sim-s tracking",
                 "wall/sim-s LOST", "LOST/tracking", "accepted", "err median m", "err > 0.5 m"],
                [[r["world"], f"{r['events_lost']}/{r['events_total']}", r["events_relocalized"],
                  fmt(r["lost_to_tracking_median_s"]), fmt(r["lost_to_tracking_max_s"]), r["episodes_total"],
                  fmt(r["episodes_median_s"]), fmt(r["episodes_max_s"]), r["episodes_unrecovered"],
                  fmt(r["wall_per_sim_s_tracking"]), fmt(r["wall_per_sim_s_lost"]),
                  fmt(r["lost_vs_tracking_wall_ratio"]), round(r["accepted_fraction"], 3),
                  fmt(r["accepted_error_median_m"]), r["accepted_over_0_5m"]] for r in results])
    args.json.parent.mkdir(parents=True, exist_ok=True)
    import json

    args.json.write_text(json.dumps({"load_average_before": load0, "load_average_after": load1,
                                     "params": {k: (str(v) if isinstance(v, Path) else v)
                                                for k, v in vars(args).items()},
                                     "worlds": results}, indent=1) + "\n")
    print(f"wrote {args.json}")
    png = args.json.with_suffix(".png")
    plot(results, png, args.blackout_s)
    print(f"wrote {png}")


def plot(results: list[dict[str, Any]], path: Path, blackout_s: float) -> None:
    """Per world: each VLoc call's wall time against sensor time (LL / GL, accepted or not),
    the faults shaded, and the bound on a recovering GL query (2x the LL median) as a line."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(results), 1, figsize=(12, 3.2 * len(results)), squeeze=False)
    for ax, r in zip(axes[:, 0], results, strict=True):
        qs = r["queries"]
        t0 = qs[0]["t"]
        for e in r["events"]:
            t = e["t_fault_s"]
            ax.axvspan(t, t + (blackout_s if e["kind"] == "blackout" else 1.0),
                       color="0.8" if e["kind"] == "blackout" else "#f4c2c2", zorder=0)
            ax.text(t, 1.0, e["kind"], transform=ax.get_xaxis_transform(), fontsize=7, va="top")
        for mode, acc, style, label in (("local", True, "o", "LL accepted"), ("local", False, "x", "LL not"),
                                        ("global", True, "^", "GL accepted"), ("global", False, "v", "GL not")):
            pts = [(x["t"] - t0, x["wall_s"] * 1e3) for x in qs if x["mode"] == mode and x["accepted"] == acc]
            if pts:
                t, w = zip(*pts, strict=True)
                ax.plot(t, w, style, ms=4, label=label,
                        color={"local": "tab:green", "global": "tab:blue"}[mode] if acc else
                        {"local": "tab:orange", "global": "tab:red"}[mode])
        if r["ll_query_wall_ms_median"] is not None:
            ax.axhline(2 * r["ll_query_wall_ms_median"], color="k", ls="--", lw=0.8, label="2x LL median")
        ax.set_ylabel("VLoc call wall ms")
        ratio, med = r["lost_vs_tracking_wall_ratio"], r["lost_to_tracking_median_s"]
        ax.set_title(f"{r['world']}: LOST/tracking wall {'-' if ratio is None else f'{ratio:.2f}x'}, "
                     f"relocalized {r['events_relocalized']}/{r['events_lost']} faults, "
                     f"median {'-' if med is None else f'{med:.1f}'} s", fontsize=9)
        ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    axes[-1, 0].set_xlabel("sensor time s")
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


if __name__ == "__main__":
    raise SystemExit(main())
