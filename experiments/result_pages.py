"""The per-benchmark result pages under docs/results/, regenerated from the benchmarks' own JSON
(`python bench/report.py`, beside the headline table of `experiments.report`).

Each `Page` is one benchmark family's dated table: the page is written whole (title, where it
comes from, the reference doc that says how to read it), and between the markers
`<!-- figures:begin -->` / `<!-- figures:end -->` the date, machine and command of the run and
one row per case. A page whose JSON is missing (or lacks a figure) keeps its committed block,
and the run says so.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from litevloc.experiments.report import BEGIN, END, Json, cell, machine, measured_on


@dataclass(frozen=True)
class Page:
    """`docs/results/<name>.md`: `title`, the JSON it reads (relative to `out/`), the command that
    writes it, the reference doc (relative to docs/) that explains it, the columns and the rows."""

    name: str
    title: str
    json: str
    command: str
    doc: str
    columns: tuple[str, ...]
    rows: Callable[[Json], list[list[str]]]


def _splits_rows(d: Json) -> list[list[str]]:
    out = []
    for r in d["splits"]:
        s = r["summary"]
        out.append([r["split"] + ("*" if r["role"] == "choose" else ""), f"{s['covered_pct']:.1f}",
                    f"{s['accepted_pct']:.1f}", f"{s['accepted_of_covered_pct']:.1f}",
                    f"{s['within_5cm_5deg_pct']:.1f}", f"{s['median_cm']:.2f} / {s['max_cm']:.1f}",
                    str(s["wrong_over_0.5m"]), f"{s['vpr_recall@10_covered_pct']:.0f}",
                    f"{s['gl_latency_median_ms']:.0f}"])
    return out


def _prior_gate_rows(d: Json) -> list[list[str]]:
    return [[r["pass"].removeprefix("sim:"), f"{r['age_s']:g} s",
             f"{100 * r['err_median_m']:.1f} / {100 * r['err_max_m']:.1f}", f"{r['z_max']:.2f}",
             f"{r['gate_axis_median_m']:.2f} ({r['age_gate_m']:.2f})", f"{r['right_refused']} of {r['windows']}"]
            for r in d["results"]]


def _opt(v: float | None, fmt: str, scale: float = 1.0) -> str:
    """`v` x `scale` formatted, "-" where the run has no such figure (None)."""
    return "-" if v is None else format(v if scale == 1.0 else scale * v, fmt)


def _slam_rows(d: Json) -> list[list[str]]:
    cases = [(name, c) for name, c in d.items() if isinstance(c, dict) and "s_per_keyframe" in c]
    return [[name, _opt(c.get("keyframe_ate_m"), ".1f", 100), _opt(c.get("odometry_ate_m"), ".0f", 100),
             _opt(c.get("no_loop_ate_m"), ".1f", 100), _opt(c.get("loops_kept"), "d"),
             _opt(c.get("wrong_loops_kept"), "d"),
             f"{c['s_per_keyframe']:.2f} ({_opt(c.get('cpu_s_per_keyframe'), '.1f')})",
             f"{_opt(c.get('map_keyframes'), 'd')} / {_opt(c.get('slam_keyframes'), 'd')}"] for name, c in cases]


def _pct(v: float | None) -> str:
    return _opt(v, ".1f", 100)


def _goals(r: Json) -> str:
    return "-" if r["goals_total"] is None else f"{r['goals_reached']}/{r['goals_total']}"


def _change_rows(d: Json) -> list[list[str]]:
    return [[c["axis"], f"{c['level']:g}", f"{_pct(c['gl_accepted_of_covered'])} "
             f"({_pct(c['gl_accepted_of_covered_unchanged'])})", str(c["wrong_over_0_5m"]),
             f"{_goals(c)} ({_opt(c['goals_reached_unchanged'], 'd')})",
             _pct(c["after_update"]["gl_accepted_of_covered"]), str(c["after_update"]["wrong_over_0_5m"]),
             _goals(c["after_update"])] for c in d["cases"]]


def _cycle_rows(d: Json) -> list[list[str]]:
    return [[str(c["cycle"]), f"{c['map_size_ratio']:.2f}", f"{c['map_size_ratio_to_first_update']:.2f}",
             _pct(c["gl_accepted_of_covered"])] for c in d["update_cycles"]]


def _verdict(r: Json) -> str:
    """robot0's push: published or refused (absent from a run without a push)."""
    pub = r.get("push_published")
    return "-" if pub is None else "published" if pub else "refused"


def _held_out(r: Json) -> str:
    """The push gate's held-out check: frames localized with the current version -> the candidate."""
    d = r.get("push_details") or {}
    cur, cand = d.get("current"), d.get("candidate")
    if not cur or not cand:
        return "-"
    return f"{cur['accepted']}/{cur['queries']} -> {cand['accepted']}/{cand['queries']}"


def _total(xs: list[int] | None) -> int | None:
    return None if xs is None else sum(xs)


def _earliest(xs: list[float | None] | None) -> float | None:
    vals = [x for x in xs or [] if x is not None]
    return min(vals) if vals else None


def _not_in_control(r: Json) -> str:
    """LOST stretches of the run that its control without the push does not have, all robots
    ('-': no control was run)."""
    per_robot = r.get("lost_spans_not_in_control_per_robot")
    if per_robot is None:
        return "-"
    own = [f"{a:.1f}-{b:.1f} s" for spans in per_robot for a, b in spans]
    total = sum(len(spans) for spans in r["lost_spans_s_per_robot"])
    ctrl = sum(len(spans) for spans in r["control_lost_spans_s_per_robot"])
    return f"{len(own)} of {total} (control: {ctrl})" + (f": {', '.join(own)}" if own else "")


def _fleet_rows(d: Json) -> list[list[str]]:
    def per_robot(xs: list[float | None], fmt: str) -> str:
        return " ".join(_opt(x, fmt) for x in xs)

    return [[str(r["robots"]), f"{r['fetch_s']:.2f} ({r['fetch_bytes'] / 1e6:.1f} MB)",
             f"{_opt(r.get('push_s'), '.1f')} ({_verdict(r)})", _held_out(r),
             _opt(r.get("push_to_all_switched_s"), ".1f"),
             f"{_opt(r['switch_s_max'], '.1f')} ({r.get('robots_switched', '-')}/{r['robots']})",
             f"{_opt(_total(r.get('lost_poses_before_announce')), 'd')} / {r['lost_during_switch']}",
             _opt(_earliest(r.get("first_lost_after_switch_s")), ".1f"), _not_in_control(r),
             _opt(r["max_jump_m"], ".1f", 100),
             per_robot(r["vloc_hz_per_robot"], ".2f"),
             per_robot(r["cpu_s_per_vloc"], ".2f"),
             f"{r['server_rss_mb']:.0f} / {_opt(r.get('server_cpu_percent'), '.1f')}",
             _opt(r["wire_bytes_per_robot_per_min"], ".0f", 1e-3)] for r in d["runs"]]


PAGES: tuple[Page, ...] = (
    Page("splits", "7-Scenes cross-split localization", "bench/splits.json", "python bench/splits.py",
         "localization.md#the-cross-split-benchmark-python-benchsplitspy",
         ("split (* = choosing)", "covered %", "accepted %", "accepted among covered %", "within [5 cm, 5 deg] %",
          "median / max cm", "> 0.5 m", "R@10 among covered %", "GL median ms"), _splits_rows),
    Page("prior_gate", "The fused prior's covariance against the simulator's odometry drift",
         "bench/prior_gate.json", "python bench/prior_gate.py", "localization.md#the-prior-gate",
         ("pass", "odometry alone", "error median / max cm", "error / sigma, max",
          "gate along the axis, median m (age gate m)", "true pose refused"), _prior_gate_rows),
    Page("slam", "Maps posed by their own SLAM", "bench/slam.json", "python bench/slam.py",
         "mapping.md#what-the-slam-does",
         ("case", "keyframe ATE cm", "odometry alone ATE cm", "without loops ATE cm", "loops kept", "wrong loops kept",
          "s per map keyframe (CPU-s)", "map / SLAM keyframes"), _slam_rows),
    Page("change", "Localization and navigation in a changed building", "bench/change.json",
         "python bench/change.py", "simulator.md#a-building-some-time-later-the-change-block",
         ("axis", "level", "GL accepted among covered % (unchanged)", "> 0.5 m", "goals reached (unchanged)",
          "after update: GL %", "after update: > 0.5 m", "after update: goals"), _change_rows),
    Page("change_cycles", "A map updated again and again in a building that keeps changing", "bench/change_cycles.json",
         "python bench/change.py --mix-only --cycles 10 --json out/bench/change_cycles.json",
         "simulator.md#a-building-some-time-later-the-change-block",
         ("cycle", "map size / before any update", "map size / after the first update",
          "GL accepted among covered %"), _cycle_rows),
    Page("fleet", "Robots on one served map, and one robot's pushed update switched to by all", "bench/fleet.json",
         "python bench/fleet.py --robots 1 2 4 --control", "fleet.md#the-fleet-benchmark",
         ("robots", "fetch s (size)", "push -> published s (verdict)", "held-out localized: current -> candidate",
          "push -> last switched s", "announce -> last switched s (switched)",
          "LOST poses before / after announce", "switch -> first LOST s",
          "LOST stretches not in the control (all robots)",
          "pose step at the switch cm", "VLoc Hz per robot", "CPU-s per VLoc per robot", "server RSS MB / CPU %",
          "wire kB per robot per min"), _fleet_rows),
)


def page_block(page: Page, path: Path) -> str:
    """The block between the markers from the JSON file at `path` (KeyError/ValueError when it
    lacks a figure)."""
    d = json.loads(path.read_text())
    meta = d.get("meta", {})
    # the run's own command where the JSON records it (a smaller run than the page's default says so)
    command = f"python bench/{meta['command']}" if meta.get("command") else page.command
    pooled = " and ".join(f"`python bench/{m['command']}`" for m in meta.get("merged", []))
    runs = f", pooling {pooled}" if pooled else ""
    lines = [f"Measured {measured_on(meta, path)} on {machine(meta)} with `{command}`{runs}.", "",
             "| " + " | ".join(page.columns) + " |", "|" + "---|" * len(page.columns)]
    lines += ["| " + " | ".join(cell(c) for c in row) + " |" for row in page.rows(d)]
    return "\n".join(lines)


def page_text(page: Page, block: str) -> str:
    """The whole page: its fixed head and `block` between the markers."""
    return (f"# {page.title} (generated)\n\nWritten by `python bench/report.py` from `out/{page.json}`; do not edit "
            f"by hand. How it is measured and read: [{page.doc.split('#')[0]}](../{page.doc}).\n\n"
            f"{BEGIN}\n{block}\n{END}\n")


def committed_block(text: str) -> str | None:
    """The block between the markers of a committed page, None when it has none."""
    if BEGIN not in text or END not in text:
        return None
    return text[text.index(BEGIN) + len(BEGIN): text.index(END)].strip("\n")


def update_pages(out_dir: Path, results_dir: Path, log: Callable[[str], None] = print) -> None:
    """Rewrite every page of `PAGES` under `results_dir` from its JSON under `out_dir`."""
    for page in PAGES:
        doc, path = results_dir / f"{page.name}.md", out_dir / page.json
        block = None
        if path.is_file():
            try:
                block = page_block(page, path)
            except (KeyError, ValueError, TypeError) as exc:
                log(f"{page.name}: {path} has no figure ({type(exc).__name__}: {exc}); keeping the committed table")
        else:
            log(f"{page.name}: no {path}; keeping the committed table")
        if block is None:
            block = (committed_block(doc.read_text()) if doc.is_file() else None) or "Not measured yet."
        text = page_text(page, block)
        changed = not doc.is_file() or doc.read_text() != text
        if changed:
            doc.write_text(text)
        log(f"{doc}: {'rewritten' if changed else 'unchanged'}")
