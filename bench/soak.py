"""Soak benchmark: the full onboard service for >= 30 minutes of sensor time at 2x real time.

The recording (default: the simulated office's query pass, 122 s, recorded with its map under
out/bench/inputs/office when absent, see `_common.office_inputs`) is turned once into
a *ping-pong* recording (the pass, then the same pass backwards in time, stamps mirrored)
in `out/bench/soak_pingpong.mcap`: its last pose is its first, so looping it with a time
offset per lap keeps stamps increasing and odometry, images and ground truth continuous
across every seam. That loop is fed through the real service (map, ONNX models, VLoc,
GTSAM fusion, Zenoh publishing) in its own process at `--rate` (2x) real time; a Zenoh
probe in a second process subscribes to `litevloc/pose` and measures wire latency.

Every `--sample-s` seconds the service process records RSS, queue depths, stage latencies,
VLoc rate and fused-pose rate. Targets evaluated at the end:

* zero odometry messages lost (odometry in == fused, odometry FIFO never overflowed);
* RSS growth < 5 % from the end of the warm-up (`--warmup-min`, 2 min) to the end;
* no stage stalls: VLoc calls, fused odometry and published poses never stand still for
  more than `--stall-s` (20 s wall), no stage failed or errored, and no queue's oldest item
  was older than that;
* fused latency (odometry in -> pose handed to Zenoh) p99 of the first vs the last
  5 minutes of the run (ratio reported; "unchanged" = last <= 1.5x first + 0.5 ms).

Config: the `default` preset plus SOAK_OVERRIDES (fusion window 12 s, see there) and `--set`.

    python bench/soak.py                           # 30 min sensor time = 15 min wall (+ inputs once)
    python bench/soak.py --minutes 2 --warmup-min 0.5 --window-min 0.5   # the short one of `make bench`

Writes out/bench/soak.json and out/bench/soak.png and prints a table.
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import json
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _common import OUT, ROOT, office_inputs, print_table, write_json

from litevloc.base.process_usage import memory_mb

# At 2x real time a VLoc result arrives twice as late in sensor time: a 1-3 s VLoc step on a
# shared 2-core machine is 2-6 s of sensor time, beyond fusion's default 3 s smoother window
# (results are then refused as too old and fusion never initialises). The soak widens it.
SOAK_OVERRIDES = ["fusion.params.lag_s=12", "fusion.params.odom_buffer_s=14"]


def make_pingpong(rec: Path, dst: Path) -> Path:
    """Write `rec` forward then backward in time (stamps mirrored after the end) to `dst`.

    The backward half has stamp `2 * end + gap - t` for a message at `t` (gap = 5 ms), so
    the pose at its start equals the pose at the end of the forward half and its last
    pose equals the very first one: looping the result keeps every stream continuous."""
    import dataclasses as dc

    from litevloc.hw.streams.mcap_io import McapRecorder, McapSource

    if dst.is_file() and dst.stat().st_mtime > rec.stat().st_mtime:
        return dst
    src = McapSource(rec, strict=True)
    end, gap = src.end_ns, 5_000_000
    tmp = dst.with_suffix(".partial")
    with McapRecorder(tmp, metadata={"pingpong_of": str(rec)}) as out:
        for m in McapSource(rec, strict=True):
            out.write(m)
        for m in McapSource(rec, strict=True):  # written in decreasing time; MCAP readers sort by log time
            out.write(dc.replace(m, t_ns=2 * end + gap - m.t_ns))
    tmp.replace(dst)
    return dst


def looped(rec: Path, seconds: float, gap_ns: int = 5_000_000) -> Iterator[Any]:
    """Messages of `rec` repeated with a time offset per lap until `seconds` of sensor time."""
    from litevloc.hw.streams.mcap_io import McapSource

    first = McapSource(rec, strict=False)
    period = first.end_ns - first.start_ns + gap_ns
    t_end = first.start_ns + int(seconds * 1e9)
    lap, index_offset = 0, 0
    while True:
        src = first if lap == 0 else McapSource(rec, strict=False)
        off = lap * period
        n = 0
        for m in src:
            t = m.t_ns + off
            if t > t_end:
                return
            if hasattr(m, "index"):
                n = max(n, m.index + 1)
                yield dataclasses.replace(m, t_ns=t, index=m.index + index_offset)
            else:
                yield dataclasses.replace(m, t_ns=t)
        lap += 1
        index_offset += n


def one_run(rec: Path, map_dir: Path, minutes: float, rate: float, endpoint: str, out: Path,
            sample_s: float, window_min: float, overrides: list[str]) -> None:
    from litevloc.config import load_config
    from litevloc.runtime.service.app import build_app, with_endpoints

    cfg = load_config("default", ["runtime.mode=realtime", *SOAK_OVERRIDES, *overrides])
    cfg = with_endpoints(cfg, [], [endpoint], None)
    cfg = dataclasses.replace(cfg, zenoh=dataclasses.replace(cfg.zenoh, listen=()))
    app = build_app(cfg, map_dir, looped(rec, minutes * 60.0), rate, record=False)  # as `litevloc run`
    svc = app.service
    # Measurement must not grow with the run: latencies and pose errors are binned per sample.
    from collections import deque

    import numpy as np

    n_win = max(1, round(window_min * 60.0 / rate / sample_s))
    lat_bin: list[float] = []
    lat_first: list[np.ndarray] = []  # per sample interval, float32 ms, first window
    lat_last: deque[np.ndarray] = deque(maxlen=n_win)
    err_bin: list[float] = []
    gt_recent: dict[int, np.ndarray] = {}
    ate_acc = {"sq": 0.0, "n": 0, "max": 0.0}
    t0 = time.monotonic()
    orig = svc.e2e.add_since

    def add_since(t_in: int) -> float:  # publisher thread
        ms = orig(t_in)
        lat_bin.append(ms)
        return ms

    def on_gt(gt: Any) -> None:  # source thread
        gt_recent[int(gt.t_ns)] = gt.T_world_camera
        if len(gt_recent) > 64:
            gt_recent.pop(next(iter(gt_recent)))

    def on_fused(f: Any) -> None:  # fusion thread
        if not getattr(f, "initialised", True):
            return
        t = int(f.t_ns)
        for g_t, g_T in list(gt_recent.items()):
            if abs(g_t - t) <= 3_000_000:
                e = float(np.linalg.norm((np.asarray(f.T_map_base) @ app.T_base_camera)[:3, 3] - g_T[:3, 3]))
                err_bin.append(e)
                ate_acc["sq"] += e * e
                ate_acc["n"] += 1
                ate_acc["max"] = max(ate_acc["max"], e)
                break

    svc.e2e.add_since = add_since
    prev_fused = svc.core.on_fused  # the core calls it for every fused pose (the service shell does not)

    def fused_hook(f: Any) -> None:
        if prev_fused is not None:
            prev_fused(f)
        on_fused(f)

    svc.on_ground_truth, svc.core.on_fused = on_gt, fused_hook
    samples: list[dict[str, Any]] = []
    done = threading.Event()

    def sampler() -> None:
        while not done.wait(sample_s):
            st = svc.status()
            q = st["queues"]
            lat = np.asarray(lat_bin[:], dtype=np.float32)
            del lat_bin[: lat.size]
            err = np.asarray(err_bin[:], dtype=np.float64)
            del err_bin[: err.size]
            if len(lat_first) < n_win:
                lat_first.append(lat)
            lat_last.append(lat)
            samples.append({
                "wall_s": time.monotonic() - t0, "sensor_s": (st.get("sensor_time_ns") or 0) * 1e-9,
                "rss_mb": memory_mb()["rss"], "counters": st["counters"],
                "queue_depth": {k: v["depth"] for k, v in q.items()},
                "queue_age_oldest_ms": {k: v["age_oldest_ms"] for k, v in q.items()},
                "queue_overflows": {k: v["overflows"] for k, v in q.items()},
                "stage_p99_ms": {n: {k: v["p99_ms"] for k, v in s.get("latency", {}).items()}
                                 for n, s in st["stages"].items()},
                "stage_errors": {n: s["errors"] for n, s in st["stages"].items()},
                "state": st["state"],
                "fused_p99_ms": float(np.percentile(lat, 99)) if lat.size else None,
                "pose_error_median_m": float(np.median(err)) if err.size else None,
                "pose_error_max_m": float(err.max()) if err.size else None,
            })

    th = threading.Thread(target=sampler, daemon=True)
    th.start()
    res = svc.run()
    done.set()
    th.join()
    wall = time.monotonic() - t0
    app.close()
    first = np.concatenate(lat_first) if lat_first else np.zeros(0)
    last = np.concatenate(list(lat_last)) if lat_last else np.zeros(0)
    ate = None if not ate_acc["n"] else {"rmse": float(np.sqrt(ate_acc["sq"] / ate_acc["n"])),
                                         "max": ate_acc["max"], "n": ate_acc["n"]}
    out.write_text(json.dumps({
        "ok": res.ok, "reason": res.reason, "wall_s": wall, "samples": samples, "final_status": res.status,
        "lat_first": first.tolist(), "lat_last": last.tolist(), "ate_m": ate,
    }, default=float))


def evaluate(r: dict[str, Any], warmup_min: float, stall_s: float) -> dict[str, Any]:
    import numpy as np

    samples = r["samples"]
    st = r["final_status"]
    c = st["counters"]
    oq = st["queues"]["odometry"]
    lost = (int(c["odometry_in"] - c["odometry_fused"]) + int(c.get("odometry_rejected", 0)) + int(oq["overflows"])
            + int(oq["drops"]))
    wall = np.array([s["wall_s"] for s in samples])
    rss = np.array([s["rss_mb"] for s in samples])
    warm = wall >= warmup_min * 60.0 / max(r["rate"], 1e-9)
    rss_warm = float(rss[warm][0]) if warm.any() else float("nan")
    rss_end = float(rss[-1]) if len(rss) else float("nan")
    growth = 100.0 * (rss_end - rss_warm) / rss_warm if warm.any() else float("nan")
    stalls: list[str] = []
    # A stage stalls when its counter does not move for more than `stall_s` wall seconds
    # (published poses only count once fusion is initialised).
    for k in ("vloc_calls", "odometry_fused", "poses_published"):
        last_change = samples[0]["wall_s"] if samples else 0.0
        for a, b in itertools.pairwise(samples):
            if b["counters"][k] != a["counters"][k] or (k == "poses_published" and a["state"] == "INIT"):
                last_change = b["wall_s"]
            elif b["wall_s"] - last_change > stall_s:
                stalls.append(f"{k} did not advance from {last_change:.0f} s to {b['wall_s']:.0f} s")
                last_change = b["wall_s"]
    for a, b in itertools.pairwise(samples):
        for q, age in b["queue_age_oldest_ms"].items():
            if age is not None and np.isfinite(age) and age > stall_s * 1e3:
                stalls.append(f"queue {q}: oldest item {age / 1e3:.1f} s old at {b['wall_s']:.0f} s")
        for n, e in b["stage_errors"].items():
            if e > a["stage_errors"].get(n, 0):
                stalls.append(f"stage {n}: {e} error(s) at {b['wall_s']:.0f} s")
    for n, s in st["stages"].items():
        if s["state"] == "FAILED":
            stalls.append(f"stage {n} FAILED: {s['last_error']}")
    first, last = np.asarray(r["lat_first"]), np.asarray(r["lat_last"])
    lm = np.concatenate([first, last])
    p99_first = float(np.percentile(first, 99)) if first.size else float("nan")
    p99_last = float(np.percentile(last, 99)) if last.size else float("nan")
    sensor_s = samples[-1]["sensor_s"] - samples[0]["sensor_s"] if len(samples) > 1 else float("nan")
    dur = wall[-1] - wall[0] if len(wall) > 1 else float("nan")
    return {
        "odometry_in": c["odometry_in"], "odometry_fused": c["odometry_fused"], "odometry_lost": lost,
        "rss_warm_mb": rss_warm, "rss_end_mb": rss_end, "rss_max_mb": float(rss.max()) if len(rss) else None,
        "rss_growth_percent": growth, "stalls": stalls[:20], "n_stalls": len(stalls),
        "latency_p99_first_ms": p99_first, "latency_p99_last_ms": p99_last,
        "latency_p99_ratio": p99_last / p99_first if p99_first > 0 else float("nan"),
        "latency_p50_ms": float(np.median(lm)) if lm.size else float("nan"),
        "latency_p99_ms": float(np.percentile(lm, 99)) if lm.size else float("nan"),
        "vloc_hz_wall": (samples[-1]["counters"]["vloc_calls"] - samples[0]["counters"]["vloc_calls"]) / dur,
        "fused_hz_wall": (samples[-1]["counters"]["poses_published"] - samples[0]["counters"]["poses_published"])
        / dur,
        "sensor_seconds_sampled": sensor_s,
        "targets": {
            "zero_odometry_lost": lost == 0,
            "rss_growth_below_5_percent": bool(growth < 5.0),
            "no_stage_stalls": not stalls,
            "fused_p99_unchanged": bool(p99_last <= 1.5 * p99_first + 0.5),
        },
    }


def plot(r: dict[str, Any], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    s = r["samples"]
    t = np.array([x["sensor_s"] for x in s]) / 60.0
    fig, ax = plt.subplots(2, 3, figsize=(15, 7), sharex=True)
    ax[0, 0].plot(t, [x["rss_mb"] for x in s])
    ax[0, 0].set_ylabel("RSS MB")
    for q in s[0]["queue_depth"]:
        ax[0, 1].plot(t, [x["queue_depth"][q] for x in s], label=q)
    ax[0, 1].set_ylabel("queue depth")
    ax[0, 1].legend(fontsize=8)
    c = np.array([[x["counters"]["vloc_calls"], x["counters"]["poses_published"]] for x in s], dtype=float)
    w = np.array([x["wall_s"] for x in s])
    dt = np.maximum(np.diff(w), 1e-9)
    ax[1, 0].plot(t[1:], np.diff(c[:, 0]) / dt, label="VLoc Hz")
    ax[1, 0].plot(t[1:], np.diff(c[:, 1]) / dt / 100.0, label="fused poses Hz / 100")
    ax[1, 0].set_ylabel("rate (wall)")
    ax[1, 0].legend(fontsize=8)
    for name in ("vloc", "fusion", "publisher"):
        for inp in s[0]["stage_p99_ms"].get(name, {}):
            ax[1, 1].plot(t, [x["stage_p99_ms"][name].get(inp) for x in s], label=f"{name}:{inp} p99")
    ax[1, 1].set_yscale("log")
    ax[1, 1].set_ylabel("stage latency p99 ms")
    ax[1, 1].legend(fontsize=7)
    ax[0, 2].plot(t, [x["fused_p99_ms"] for x in s])
    ax[0, 2].set_ylabel("fused pose latency p99 per interval, ms")
    ax[1, 2].plot(t, [x["pose_error_median_m"] for x in s], label="median")
    ax[1, 2].plot(t, [x["pose_error_max_m"] for x in s], label="max")
    ax[1, 2].set_ylabel("fused camera position error, m")
    ax[1, 2].legend(fontsize=8)
    for a in ax[1]:
        a.set_xlabel("sensor time (min)")
    fig.suptitle(f"soak: {r['minutes']:.0f} min sensor time at {r['rate']:g}x")
    fig.tight_layout()
    fig.savefig(path, dpi=90)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rec", type=Path, default=None, help="recording (default: the office query pass, made if absent)")
    ap.add_argument("--map", type=Path, default=None, help="map (default: the office map, made if absent)")
    ap.add_argument("--minutes", type=float, default=30.0, help="sensor minutes (default 30)")
    ap.add_argument("--rate", type=float, default=2.0, help="real-time factor (default 2)")
    ap.add_argument("--sample-s", type=float, default=5.0)
    ap.add_argument("--warmup-min", type=float, default=2.0, help="sensor minutes before the RSS baseline")
    ap.add_argument("--window-min", type=float, default=5.0, help="sensor minutes of the first/last latency window")
    ap.add_argument("--stall-s", type=float, default=20.0,
                    help="a stage whose count does not move, or a queue item older than this (wall s), is a stall")
    ap.add_argument("--set", dest="overrides", action="append", default=[],
                    help="config override (after the soak's own, see SOAK_OVERRIDES)")
    ap.add_argument("--reuse", action="store_true", help="evaluate out/bench/soak_run.json again, do not run")
    ap.add_argument("--one", nargs=3, metavar=("REC", "ENDPOINT", "OUT"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.one:
        one_run(Path(args.one[0]), args.map, args.minutes, args.rate, args.one[1], Path(args.one[2]), args.sample_s,
                args.window_min, args.overrides)
        return
    if args.rec is None or args.map is None:
        office_map, office_query = office_inputs()
        args.map = args.map or office_map
        args.rec = args.rec or office_query
    if not args.rec.is_file() or not (args.map / "manifest.json").is_file():
        raise SystemExit(f"needs a recording and a map: {args.rec} / {args.map} not found")
    OUT.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    pp = make_pingpong(args.rec, OUT / "soak_pingpong.mcap")
    print(f"ping-pong recording {pp} ready in {time.perf_counter() - t0:.1f} s")
    sys.path.insert(0, str(ROOT / "tests" / "runtime"))
    from zenoh_helpers import free_port

    wall_limit = args.minutes * 60.0 / args.rate
    run_out, probe_out = OUT / "soak_run.json", OUT / "soak_probe.json"
    if not args.reuse:
        ep = f"tcp/127.0.0.1:{free_port()}"
        probe_out.unlink(missing_ok=True)
        probe = subprocess.Popen(
            [sys.executable, "-m", "litevloc.runtime.transport.probe", "--listen", ep, "--topics", "pose",
             "--timeout", str(wall_limit * 3 + 300), "--idle", "30", "--json", str(probe_out)],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        assert probe.stdout is not None
        line = probe.stdout.readline().strip()
        if line != "READY":
            probe.kill()
            raise SystemExit(f"probe did not start: {line!r} {probe.communicate()[1][-2000:]}")
        subprocess.run([sys.executable, __file__, "--map", str(args.map), "--minutes", str(args.minutes),
                        "--rate", str(args.rate), "--sample-s", str(args.sample_s),
                        "--window-min", str(args.window_min),
                        *[a for o in args.overrides for a in ("--set", o)],
                        "--one", str(pp), ep, str(run_out)], check=True)
        probe.communicate(timeout=120)
    wire = json.loads(probe_out.read_text())["topics"]["pose"] if probe_out.is_file() else {}
    r = json.loads(run_out.read_text())
    r.update(minutes=args.minutes, rate=args.rate)
    ev = evaluate(r, args.warmup_min, args.stall_s)
    ev["wire_latency"] = wire.get("latency", {})
    ev["poses_received"] = wire.get("count")
    ev["ate_m"] = r["ate_m"]
    png = OUT / "soak.png"
    plot(r, png)
    rows = [
        ["sensor time / wall time", f"{args.minutes:g} min / {r['wall_s'] / 60:.1f} min", f"{args.rate:g}x"],
        ["odometry in / fused / lost", f"{ev['odometry_in']} / {ev['odometry_fused']} / {ev['odometry_lost']}",
         "PASS" if ev["targets"]["zero_odometry_lost"] else "FAIL"],
        ["RSS after warm-up -> end (max) MB",
         f"{ev['rss_warm_mb']:.0f} -> {ev['rss_end_mb']:.0f} ({ev['rss_max_mb']:.0f}), "
         f"{ev['rss_growth_percent']:+.1f} %", "PASS" if ev["targets"]["rss_growth_below_5_percent"] else "FAIL"],
        ["stage stalls", str(ev["n_stalls"]), "PASS" if ev["targets"]["no_stage_stalls"] else "FAIL"],
        [f"fused p99 first / last {args.window_min:g} min (ms)",
         f"{ev['latency_p99_first_ms']:.2f} / {ev['latency_p99_last_ms']:.2f} (x{ev['latency_p99_ratio']:.2f})",
         "PASS" if ev["targets"]["fused_p99_unchanged"] else "FAIL"],
        ["fused latency p50 / p99, first+last windows (ms)",
         f"{ev['latency_p50_ms']:.2f} / {ev['latency_p99_ms']:.2f}", ""],
        ["wire latency p50 / p99 (ms), probe process",
         f"{ev['wire_latency'].get('median_ms', float('nan')):.2f} / "
         f"{ev['wire_latency'].get('p99_ms', float('nan')):.2f}", ""],
        ["VLoc Hz / fused poses Hz (wall)", f"{ev['vloc_hz_wall']:.2f} / {ev['fused_hz_wall']:.0f}", ""],
        ["poses received by probe", str(ev["poses_received"]), ""],
        ["camera ATE RMSE / max (cm)", "n/a" if not r["ate_m"] else
         f"{100 * r['ate_m']['rmse']:.1f} / {100 * r['ate_m']['max']:.1f}", ""],
        ["service end", f"{r['reason']} (ok={r['ok']})", ""],
    ]
    print_table(f"Soak: {args.rec.name} ping-pong looped to {args.minutes:g} min at {args.rate:g}x, 2 CPUs",
                ["metric", "value", "target"], rows)
    for s in ev["stalls"]:
        print("  stall:", s)
    print(f"plot: {png}")
    write_json("soak", {"args": {k: str(v) for k, v in vars(args).items()}, "wall_s": r["wall_s"], **ev,
                        "samples": r["samples"], "final_status": r["final_status"]})


if __name__ == "__main__":
    main()
