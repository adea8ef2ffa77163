"""The headline figures table of README.md and docs/results/figures.md, regenerated from the
benchmarks' own JSON (`python bench/report.py`).

Each `Headline` names a benchmark's JSON file under `out/` and how to read one line from it.
The table is rewritten between the markers `<!-- figures:begin -->` and `<!-- figures:end -->`;
a headline whose JSON is missing (or unreadable) keeps the row last committed, and the run
says so. No cell is longer than `MAX_CELL` characters.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

BEGIN, END = "<!-- figures:begin -->", "<!-- figures:end -->"
HEADER = ("| what | figure | measured | machine | command |", "|---|---|---|---|---|")
MAX_CELL = 300
Json = Mapping[str, Any]


@dataclass(frozen=True)
class Headline:
    """One row: `what` it measures, the JSON it reads (relative to `out/`) and the command."""

    what: str
    json: str
    command: str
    figure: Callable[[Json], str]


def _first(results: list[Json], config: str) -> Json:
    return next(r for r in results if r["config"] == config)


def _accuracy(d: Json) -> str:
    r = _first(d["results"], "joint")
    return (f"{r['within_5cm_5deg_pct']:.1f} % within [5 cm, 5 deg], median {r['median_cm']:.2f} cm / "
            f"{r['median_deg']:.2f} deg, {r['accepted_pct']:.1f} % accepted; "
            f"LL median {r['ll_latency_median_ms']:.0f} ms")


def _global_loc(d: Json) -> str:
    return (f"{d['success_pct']:.0f} % of {d['queries']} query frames localized from no prior, worst "
            f"{100 * d['max_m']:.0f} cm, median {d['time_median_ms']:.0f} ms per query")


def _splits(d: Json) -> str:
    rows = [(r["split"], r["summary"]) for r in d["splits"]]
    short = [f"{name} {s['accepted_of_covered_pct']:.1f} %" for name, s in rows if s["accepted_of_covered_pct"] < 95]
    wrong = sum(s["wrong_over_0.5m"] for _, s in rows)
    pub = next((s for name, s in rows if name == "published"), None)
    out = (f"covered frames accepted >= 95 % on {len(rows) - len(short)} of {len(rows)} splits"
           + (f" ({', '.join(short)})" if short else "") + f", {wrong} pose{'' if wrong == 1 else 's'} > 0.5 m off")
    if pub is not None:
        out += f"; published split {pub['accepted_pct']:.1f} % accepted, GL median {pub['gl_latency_median_ms']:.0f} ms"
    return out


def _navigation(demo: Json) -> str:
    d = demo["navigation"]
    out = f"{d['goals_reached']}/{d['goals_total']} goal images reached"
    base = d.get("baseline")
    if base:
        out += (f" ({base['goals_reached']}/{base['goals_total']} with ground-truth localization, path "
                f"x{d['ratios']['path_length']})")
    return out + f", {d['collisions']} collisions"


def _runtime(d: Json) -> str:
    r = d["realtime"]
    return (f"VLoc {r['vloc_hz']:.2f} Hz, fused pose p99 {r['latency']['p99_ms']:.1f} ms in the service + "
            f"{r['wire_latency']['p99_ms']:.1f} ms on the wire, {int(r['odometry_lost'])} odometry lost, "
            f"RSS {r['peak_rss_mb']:.0f} MB")


def _loop(d: Json) -> str:
    q = d["query"]
    out = (f"VLoc {100 * q['localized_fraction']:.0f} % accepted ({q['vloc_accepted_over_0_5m']} > 0.5 m off), "
           f"ATE VLoc {100 * d['vloc_ate_m']:.1f} cm, fused {100 * d['fused_ate_m']:.1f} cm; map "
           f"{d['map_bytes_per_100m'] / 1e6:.2f} MB per 100 m")
    if d.get("goals_total"):
        out += f"; {d['goals_reached']}/{d['goals_total']} goals"
    return out


def _streams(d: Json) -> str:
    return (f"MCAP replay {d['replay_fps']:.0f} frames/s (decode included), x{d['replay_vs_folder_ratio']:.1f} "
            "the dataset folder")


def _soak(d: Json) -> str:
    return (f"{d['odometry_lost']} of {d['odometry_in']} odometry lost, RSS {d['rss_growth_percent']:+.1f} % after "
            f"warm-up, fused p99 {d['latency_p99_first_ms']:.1f} -> {d['latency_p99_last_ms']:.1f} ms "
            "first/last window")


def _merge(d: Json) -> str:
    return (f"frame error {100 * d['frame_error_m']:.2f} cm / {d['frame_error_deg']:.2f} deg from "
            f"{d['links_consistent']}/{d['links_verified']} consistent links; held-out GL in the merged map "
            f"{d['localize_merged']['accepted']}/{d['localize_merged']['queries']}")


def _update(d: Json) -> str:
    u, old, new = d["update"], d["localize_old"], d["localize_new"]
    return (f"{u['nodes_before']} -> {u['nodes_after']} keyframes in {u['seconds']:.0f} s; held-out GL "
            f"{old['accepted']}/{old['queries']} -> {new['accepted']}/{new['queries']}")


def _slam(d: Json) -> str:
    o = d["office"]
    text = (f"office mapping pass posed by its own SLAM: keyframe ATE {100 * o['keyframe_ate_m']:.1f} cm "
            f"(odometry alone {100 * o['odometry_ate_m']:.0f} cm), {o['loops_kept']} loops kept, "
            f"{o['wrong_loops_kept']} wrong; {o['s_per_keyframe']:.2f} s ({o['cpu_s_per_keyframe']:.1f} CPU-s) per map "
            "keyframe")
    f = d.get("floor")
    if f is not None:  # the 15-room floor: the pass whose corridors have no loop between their ends
        text += (f"; 15-room floor: {100 * f['keyframe_ate_m']:.1f} cm, {f['wrong_loops_kept']} wrong loops, "
                 f"{f['s_per_keyframe']:.2f} s ({f['cpu_s_per_keyframe']:.1f} CPU-s)")
    lp = d.get("loop")
    if lp is not None and lp.get("keyframe_ate_m") is not None:
        text += f"; 200 m ring corridor: {100 * lp['keyframe_ate_m']:.1f} cm, {lp['wrong_loops_kept']} wrong loops"
    return text


def _buildings(d: Json) -> str:
    t = d["totals"]
    lv, gt = t["litevloc"], t["ground-truth"]
    gens = sorted({b["generator"] for b in d["buildings"]})
    seeds = sorted({int(b["seed"]) for b in d["buildings"]})
    wrong = lv["wrong_placements"]
    return (f"{lv['reached']}/{lv['goals']} goal images reached in {t['buildings']} buildings "
            f"({'/'.join(gens)}, seeds {seeds[0]}-{seeds[-1]}) "
            f"vs {gt['reached']}/{gt['goals']} with ground-truth localization, {wrong} wrong "
            f"placement{'' if wrong == 1 else 's'}, {lv['buildings_without_collision']}/{t['buildings']} "
            "buildings without collision")


def _wheels(d: Json) -> str:
    targets = d["targets"]
    ok = [t for t in targets if t["resolved"]]
    failed = [t["target"] for t in targets if not t["resolved"]]
    detail = [f"{t['target']} {t['wheels']} wheels {t['mb']:.0f} MB, onnxruntime {t['onnxruntime']}, gtsam {t['gtsam']}"
              for t in ok if t["target"] in ("cp310-aarch64", "cp312-aarch64")]
    return (f"litevloc[{d['extra']}] resolves from binary wheels alone for {len(ok)} of {len(targets)} targets"
            + (f" (not {', '.join(failed)})" if failed else "") + ("; " + "; ".join(detail) if detail else ""))


def _gpu(d: Json) -> str:
    parts = []
    for name, r in d["results"].items():
        if r.get("status") == "ok":
            v = r["vloc"]
            parts.append(f"{name} {v['rate_hz']:.1f} Hz (median {v['median_ms']:.0f} ms, "
                         f"{v['accepted_pct']:.0f} % accepted)")
        else:
            parts.append(f"{name} not run here ({r.get('status', '?')}: no such provider in this onnxruntime)")
    return "VLoc back to back on the simulated office: " + "; ".join(parts)


def _aarch64(d: Json) -> str:
    parts = []
    loc = d.get("localize")
    if loc:
        c = loc["counts"]["x86"]
        parts.append(f"{loc['frames_both']} of {c['queries']} 7-Scenes poses (1 cm tolerance) "
                     f"{'equal' if loc['passed'] else 'NOT equal'} to x86's: at most "
                     f"{100 * loc['max_m']:.1g} cm / {loc['max_deg']:.1g} deg apart")
    m = d.get("models")
    if m:
        parts.append(f"{m['count']} ONNX models and parts {'within' if m['passed'] else 'NOT within'} tolerance, "
                     f"worst {m['worst_relative']:.0e} of an output's largest value")
    return f"aarch64 wheels under qemu: {'; '.join(parts)}; {d['wall_s'] / 60:.0f} min"


HEADLINES: tuple[Headline, ...] = (
    Headline("installs from binary wheels", "bench/wheels.json", "python bench/wheels.py", _wheels),
    Headline("7-Scenes accuracy, 500 held-out queries", "bench/accuracy.json",
             "python bench/accuracy.py --map out/bench/inputs/7scenes/map", _accuracy),
    Headline("7-Scenes global localization", "bench/global_loc.json",
             "python bench/global_loc.py out/bench/inputs/7scenes/map --config 7scenes", _global_loc),
    Headline("7-Scenes cross-split localization, 8 splits", "bench/splits.json", "python bench/splits.py", _splits),
    Headline("image-goal navigation, simulated office", "demo/demo.json", "make demo", _navigation),
    Headline("image-goal navigation, generated buildings", "bench/buildings.json", "python bench/buildings.py",
             _buildings),
    Headline("maps from the robot's own sensors", "bench/slam.json", "python bench/slam.py --cases office floor",
             _slam),
    Headline("onboard service, simulated office, real time", "bench/runtime.json",
             "python bench/runtime.py --rec out/bench/inputs/office/query.mcap --map out/bench/inputs/office/map",
             _runtime),
    Headline("200 m loop, query lap", "bench/loop.json", "python bench/loop.py", _loop),
    Headline("recordings", "bench/streams.json", "python bench/streams.py", _streams),
    Headline("soak, 2x real time", "bench/soak.json", "python bench/soak.py --minutes 2 --warmup-min 0.5 "
             "--window-min 0.5", _soak),
    Headline("map merge, 7-Scenes sessions in two frames", "bench/merge.json", "python bench/merge.py", _merge),
    Headline("map update, 7-Scenes", "bench/update.json", "python bench/update.py", _update),
    Headline("VLoc per execution provider", "bench/gpu.json", "python bench/gpu.py", _gpu),
    Headline("aarch64 (Jetson) build, emulated", "bench/aarch64.json", "make aarch64-check", _aarch64),
)


def cell(text: str) -> str:
    """One table cell: on one line, no `|`, at most `MAX_CELL` characters."""
    text = " ".join(str(text).split()).replace("|", "/")
    return text if len(text) <= MAX_CELL else text[: MAX_CELL - 3] + "..."


def machine(meta: Json) -> str:
    """The machine column: CPU, CPU count and load average of a run's `meta`."""
    if not meta:
        return "not recorded"
    parts = [str(meta.get("cpu") or meta.get("machine", "?"))]
    if meta.get("cpus"):
        parts.append(f"{meta['cpus']} CPUs")
    if meta.get("load_avg") is not None:
        parts.append(f"load {meta['load_avg']:.1f}")
    return ", ".join(parts)


def measured_on(meta: Json, path: Path) -> str:
    """The run's date (YYYY-MM-DD) from its `meta`, else the JSON file's modification date."""
    return str(meta.get("time", ""))[:10] or time.strftime("%Y-%m-%d", time.localtime(path.stat().st_mtime))


def row_from_json(h: Headline, path: Path) -> list[str]:
    """The table row of `h` from its JSON file (KeyError/ValueError when the file lacks a figure)."""
    d = json.loads(path.read_text())
    meta = d.get("meta", {})
    return [h.what, h.figure(d), measured_on(meta, path), machine(meta), f"`{h.command}`"]


def committed_rows(text: str) -> dict[str, list[str]]:
    """{what: row cells} of the table between the markers of a Markdown text."""
    if BEGIN not in text or END not in text:
        return {}
    block = text[text.index(BEGIN) + len(BEGIN): text.index(END)]
    out = {}
    for line in block.splitlines():
        if line.startswith("| ") and not line.startswith(HEADER[0]):
            cells = [c.strip() for c in line.strip().strip("|").split(" | ")]
            out[cells[0]] = cells
    return out


def build_table(out_dir: Path, committed: Mapping[str, list[str]], log: Callable[[str], None] = print) -> str:
    """The Markdown table: rows from the JSON where present, the committed row otherwise."""
    lines = list(HEADER)
    for h in HEADLINES:
        path = out_dir / h.json
        row: list[str] | None = None
        if path.is_file():
            try:
                row = row_from_json(h, path)
            except (KeyError, ValueError, TypeError, StopIteration) as exc:
                log(f"{h.what}: {path} has no figure ({type(exc).__name__}: {exc}); keeping the committed row")
        else:
            log(f"{h.what}: no {path}; keeping the committed row")
        if row is None:
            row = list(committed.get(h.what, [h.what, "not measured yet", "", "", f"`{h.command}`"]))
        lines.append("| " + " | ".join(cell(c) for c in row) + " |")
    return "\n".join(lines)


def rewrite(doc: Path, table: str) -> bool:
    """Put `table` between the markers of `doc`; True when the file changed."""
    text = doc.read_text()
    if BEGIN not in text or END not in text:
        raise ValueError(f"{doc} has no {BEGIN} ... {END} markers")
    new = text[: text.index(BEGIN) + len(BEGIN)] + "\n" + table + "\n" + text[text.index(END):]
    if new != text:
        doc.write_text(new)
    return new != text


def update_docs(out_dir: Path, docs: list[Path], log: Callable[[str], None] = print) -> str:
    """Rebuild the table (committed rows from the first document) and write it into every one."""
    table = build_table(out_dir, committed_rows(docs[0].read_text()), log)
    for doc in docs:
        log(f"{doc}: {'rewritten' if rewrite(doc, table) else 'unchanged'}")
    return table
