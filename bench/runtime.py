"""The onboard service on a recording in real time vs the sequential research-code baseline.

Runs the full runtime (map, ONNX models, GTSAM fusion, Zenoh) on the first `--seconds` of a
simulator query recording, once threaded (`runtime.mode=realtime`) and once sequential (one
thread, every message handled to completion in order, as the published research code does),
each in its own process so CPU time and peak RSS are its own. A separate Zenoh subscriber
process measures publish -> receive latency of the fused poses on the wire.

Reported: odometry-in -> pose-handed-to-Zenoh latency (p50/p99, inside the service), wire
latency (p50/p99, second process), VLoc rate, frames dropped, odometry lost, CPU %, peak RSS,
RSS growth (RSS sampled every 0.5 s: the last sample vs the first one after the service started).

Frames reach the service as `litevloc run` gives them: colour undecoded, decoded only when
VLoc takes a frame (`runtime.sources.service_messages`); mode `realtime+eager` decodes every
frame at the source as before, for an A/B in the same run (`--modes realtime realtime+eager`).

`--modes realtime realtime+alt --alt-set KEY=VALUE ...` is an A/B of any runtime setting in one
run (e.g. the fused-pose latency settings: `--alt-set runtime.fusion_rt_priority=0`).
`--modes realtime+thread realtime+process` compares VLoc in a thread of the service with VLoc
in its own process (`runtime.vloc_process`; RSS and CPU then include the child's).

`--view` compares the threaded runtime without and with the live view (`--view-save` to a
temporary .rrd: Rerun logging in the view thread) on the same input in the same run:
fused-pose p99 and VLoc rate of view-on / view-off, the items the view dropped, RSS growth.

Input: the simulated office's map and query pass (`bench/_common.office_inputs`: made here
when absent, cached under out/bench/inputs/office), or `--map` / `--rec`.

    python bench/runtime.py [--seconds 30] [--view] [--repeat 3]
"""

from __future__ import annotations

import argparse
import json
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _common import ROOT, office_inputs, print_table, write_json


class RssSampler:
    """RSS (MB) of this process plus its child processes (the VLoc process, the recording
    reader: `runtime.vloc_process`, `runtime.recording_process`) every `period_s` in a daemon
    thread."""

    def __init__(self, period_s: float = 0.5) -> None:
        import os
        import threading

        self.samples: list[float] = []
        self.pss_samples: list[float] = []  # proportional set size: shared pages split between processes
        self._page_mb = os.sysconf("SC_PAGE_SIZE") / 2**20
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._run, args=(period_s,), daemon=True)
        self._t.start()

    def _run(self, period_s: float) -> None:
        import glob

        while not self._stop.wait(period_s):
            pages = 0
            children = set()
            for name in glob.glob("/proc/self/task/*/children"):
                try:
                    with open(name) as f:
                        children.update(f.read().split())
                except OSError:
                    pass
            pss_kb = 0
            for pid in ["self", *sorted(children)]:
                try:
                    with open(f"/proc/{pid}/statm") as f:
                        pages += int(f.read().split()[1])
                    with open(f"/proc/{pid}/smaps_rollup") as f:
                        pss_kb += next(int(line.split()[1]) for line in f if line.startswith("Pss:"))
                except (OSError, StopIteration):  # a child that has ended
                    pass
            self.samples.append(pages * self._page_mb)
            self.pss_samples.append(pss_kb / 1024)

    def stop(self) -> dict[str, float]:
        self._stop.set()
        self._t.join()
        a = self.samples or [float("nan")]
        return {"first_mb": a[0], "last_mb": a[-1], "max_mb": max(a), "growth_percent": 100 * (a[-1] / a[0] - 1),
                "max_pss_mb": max(self.pss_samples or [float("nan")])}


def proc_cpu_s(pid: int | None) -> float:
    """User + system CPU seconds of process `pid` so far (/proc/PID/stat); 0 for None."""
    import os

    if pid is None:
        return 0.0
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


class GcPauses:
    """Wall time of every cyclic-GC collection in this process while installed (`gc.callbacks`):
    a collection stops every thread that wants the GIL, the fusion thread included."""

    def __init__(self) -> None:
        import gc

        self.ms: list[float] = []
        self._t0 = 0
        gc.callbacks.append(self._cb)

    def _cb(self, phase: str, info: dict) -> None:
        if phase == "start":
            self._t0 = time.perf_counter_ns()
        else:
            self.ms.append((time.perf_counter_ns() - self._t0) * 1e-6)

    def stop(self) -> dict[str, float]:
        import gc

        gc.callbacks.remove(self._cb)
        return {"count": len(self.ms), "max_ms": max(self.ms, default=0.0), "total_ms": sum(self.ms)}


# the service's latency window holds every sample of a run (it keeps the last 1024 by default:
# a p99 of the last 5 s of odometry, the ~10th-largest sample, was what differed from run to run)
ODOMETRY_HZ = 200


def one_run(mode: str, rec: Path, map_dir: Path, seconds: float, endpoint: str, out: Path,
            overrides: list[str], alt_overrides: list[str] | None = None) -> None:
    import dataclasses

    from litevloc.base.process_usage import cpu_seconds, peak_rss_mb
    from litevloc.base.stats import percentiles_ms
    from litevloc.config import load_config
    from litevloc.hw.messages import SourceMessage
    from litevloc.hw.streams.mcap_io import McapSource
    from litevloc.runtime.service.app import build_app, with_endpoints
    from litevloc.runtime.sources import service_messages

    view = mode.endswith("+view")
    eager = mode.endswith("+eager")
    placement = {"realtime+process": ["runtime.vloc_process=true"],  # VLoc in its own process / in a thread,
                 "realtime+thread": ["runtime.vloc_process=false"],  # whatever the preset says
                 "realtime+alt": alt_overrides}.get(mode, [])
    window = f"runtime.latency_window={int(seconds * ODOMETRY_HZ * 1.5) + 1024}"
    cfg = load_config("default", [f"runtime.mode={mode.split('+')[0]}", window, *overrides, *placement])
    cfg = with_endpoints(cfg, [], [endpoint], None)
    cfg = dataclasses.replace(cfg, zenoh=dataclasses.replace(cfg.zenoh, listen=()))
    src = McapSource(rec, strict=False)
    n_frames = int(seconds * 15)

    def limited() -> Iterator[SourceMessage]:
        t_end = None
        reader = cfg.runtime.recording_process and cfg.runtime.mode != "sequential"
        for m in (src if eager else service_messages(src, reader_process=reader)):
            t_end = m.t_ns + int(seconds * 1e9) if t_end is None else t_end
            if m.t_ns > t_end:
                break
            yield m

    app = build_app(cfg, map_dir, limited(), 1.0, view_save=out.with_suffix(".rrd") if view else None)
    child = app.vloc_process.pid if app.vloc_process is not None else None  # runtime.vloc_process
    cpu0, t0 = cpu_seconds(), time.perf_counter()
    child_cpu0 = proc_cpu_s(child)  # the VLoc process loaded its models before t0: not counted
    children_cpu0 = cpu_seconds(resource.RUSAGE_CHILDREN)
    rss, gc_pauses = RssSampler(), GcPauses()
    res = app.service.run()
    wall = time.perf_counter() - t0
    gc_report = gc_pauses.stop()
    e2e = app.service.e2e.snapshot()
    cpu1, self_peak_mb = cpu_seconds(), peak_rss_mb()
    rss_report = rss.stop()
    view_report = None if app.view is None else app.view.report()
    app.close()  # ends (and reaps) the VLoc process; the recording reader ended with the source
    child_cpu = cpu_seconds(resource.RUSAGE_CHILDREN) - children_cpu0 - child_cpu0
    st = res.status
    c = st.get("counters", {})
    ate = app.recorder.camera_ate(app.T_base_camera)
    out.write_text(json.dumps({
        "mode": mode, "ok": res.ok, "reason": res.reason, "wall_s": wall, "frames": n_frames,
        "cpu_percent": 100 * ((cpu1 - cpu0) + child_cpu) / wall,
        # this process and its children (VLoc process, recording reader) together: the largest
        # sampled sum, or this process's own peak where that is larger
        "peak_rss_mb": max(self_peak_mb, rss_report["max_mb"]), "self_peak_rss_mb": self_peak_mb,
        "peak_pss_mb": rss_report["max_pss_mb"],
        "vloc_process": child is not None, "counters": c, "frames_dropped": st.get("frames_dropped"),
        "vloc_hz": c.get("vloc_calls", 0) / seconds,
        "latency": percentiles_ms(e2e),  # every fused pose of the run
        # as earlier runs reported it: the status's window of the last 1024 poses
        "latency_last_1024": percentiles_ms(e2e[-1024:]), "gc": gc_report,
        "odometry_lost": c.get("odometry_in", 0) - c.get("odometry_fused", 0),
        # the fused camera positions vs the recording's ground truth (no alignment), as `replay` reports it
        "fused_ate_m": None if ate is None else ate.rmse, "fused_err_median_m": None if ate is None else ate.median,
        "rss": rss_report, "view": view_report,
        "rrd_mb": out.with_suffix(".rrd").stat().st_size / 2**20 if view else None,
    }, default=float))


def median_leaves(dicts: list[dict]) -> dict:
    """A dict shaped like dicts[0] whose numeric leaves are the median over `dicts`."""
    out: dict = {}
    for k, v in dicts[0].items():
        vals = [d.get(k) for d in dicts]
        if isinstance(v, dict):
            out[k] = median_leaves([x if isinstance(x, dict) else {} for x in vals])
        elif isinstance(v, int | float) and not isinstance(v, bool) and all(
                isinstance(x, int | float) for x in vals):
            out[k] = float(statistics.median(float(x) for x in vals))
        else:
            out[k] = v
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--rec", type=Path, default=None, help="query recording (default: the office query pass)")
    ap.add_argument("--map", type=Path, default=None, help="map folder (default: the office map)")
    ap.add_argument("--seconds", type=float, default=30.0)
    ap.add_argument("--modes", nargs="+", default=None, choices=["realtime", "sequential", "realtime+view",
                                                                     "realtime+eager", "realtime+process",
                                                                     "realtime+thread", "realtime+alt"],
                    help="default: realtime sequential (with --view: realtime realtime+view)")
    ap.add_argument("--view", action="store_true", help="compare the threaded runtime with the live view off / on")
    ap.add_argument("--set", dest="overrides", action="append", default=[], help="config override, e.g. "
                    "models.intra_op_threads=1")
    ap.add_argument("--alt-set", dest="alt_overrides", action="append", default=[],
                    help="config override of mode realtime+alt only (an A/B against realtime in the same run), "
                    "e.g. runtime.fusion_rt_priority=0")
    ap.add_argument("--repeat", type=int, default=1, help="runs per mode, interleaved; medians reported")
    ap.add_argument("--probe-rt-priority", type=int, default=10, metavar="N",
                    help="the wire probe receives in SCHED_FIFO at N, as the robot's consumer of the pose would "
                         "(default 10; 0: normal priority, as runs before measured it)")
    ap.add_argument("--one", nargs=3, metavar=("MODE", "ENDPOINT", "OUT"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.one:
        one_run(args.one[0], args.rec, args.map, args.seconds, args.one[1], Path(args.one[2]), args.overrides,
                args.alt_overrides)
        return
    if args.modes is None:
        args.modes = ["realtime", "realtime+view"] if args.view else ["realtime", "sequential"]
    if args.rec is None or args.map is None:
        map_dir, rec = office_inputs()  # made when absent, cached under out/bench/inputs/office
        args.rec, args.map = args.rec or rec, args.map or map_dir
    sys.path.insert(0, str(ROOT / "tests" / "runtime"))
    from zenoh_helpers import finish_probe, free_port, start_probe

    runs: dict[str, list[dict]] = {m: [] for m in args.modes}
    with tempfile.TemporaryDirectory() as tmp:
        for rep in range(args.repeat):  # modes interleaved, so a change in machine load hits each alike
            for mode in args.modes:
                ep = f"tcp/127.0.0.1:{free_port()}"
                probe_out, run_out = Path(tmp) / f"probe_{mode}_{rep}.json", Path(tmp) / f"run_{mode}_{rep}.json"
                sets = args.overrides + (args.alt_overrides if mode == "realtime+alt" else [])
                ros2 = next((o.split("=", 1)[1] for o in reversed(sets) if o.startswith("zenoh.ros2=")), "bridge")
                proc = start_probe(ep, probe_out, "pose", {}, timeout=args.seconds * 20 + 120, idle=15.0,
                                   listen=True, ros2=ros2, rt_priority=args.probe_rt_priority)
                subprocess.run([sys.executable, __file__, "--rec", str(args.rec), "--map", str(args.map),
                                "--seconds", str(args.seconds), *[a for o in args.overrides for a in ("--set", o)],
                                *[a for o in args.alt_overrides for a in ("--alt-set", o)],
                                "--one", mode, ep, str(run_out)], check=True)
                r = json.loads(run_out.read_text())
                if r["counters"].get("poses_published", 0) == 0:  # nothing to wait for: the probe would sit out
                    proc.kill()                                      # its timeout
                    proc.communicate(timeout=10)
                    print(f"WARNING: {mode} run {rep} published no fused pose in {args.seconds:g} s "
                          f"(counters {r['counters']})", flush=True)
                    wire = {"count": 0, "latency": {}}
                else:
                    wire = finish_probe(proc, probe_out, timeout=60)["topics"]["pose"]
                r["wire_latency"] = wire["latency"]
                r["poses_received"] = wire["count"]
                runs[mode].append(r)
    # per mode: the median of each number over the repeats (the single runs are kept in the JSON)
    results = {m: {**median_leaves(rs), "runs": rs} if len(rs) > 1 else rs[0] for m, rs in runs.items()}

    def lat(r: dict, k: str) -> float:
        return float(r["latency"].get(k) or float("nan"))

    rows = []
    names = {"realtime": "threaded runtime (realtime)", "sequential": "sequential baseline",
             "realtime+view": "threaded runtime + live view",
             "realtime+eager": "threaded runtime, every frame decoded at the source",
             "realtime+process": "threaded runtime, VLoc in its own process",
             "realtime+thread": "threaded runtime, VLoc in a thread of the service",
             "realtime+alt": "threaded runtime with " + " ".join(args.alt_overrides)}
    for name, r in ((names[m], results[m]) for m in args.modes):
        r["lag_s"] = max(r["wall_s"] - args.seconds, 0.0)
        rows.append([name, lat(r, "median_ms"), lat(r, "p99_ms"),
                     float((r.get("latency_last_1024") or {}).get("p99_ms") or float("nan")),
                     r["wire_latency"].get("median_ms", float("nan")),
                     r["wire_latency"].get("p99_ms", float("nan")), r["vloc_hz"],
                     100 * float(r.get("fused_ate_m") or float("nan")), r["frames_dropped"], r["odometry_lost"],
                     r["cpu_percent"], r["peak_rss_mb"], r["self_peak_rss_mb"], r["peak_pss_mb"],
                     r["rss"]["growth_percent"], float((r.get("gc") or {}).get("max_ms", float("nan"))),
                     r["wall_s"], r["lag_s"]])
    print_table(f"Onboard service on {args.seconds:.0f} s of {args.rec.name} (15 Hz camera, 200 Hz odometry), 2 CPUs",
                ["mode", "in-service p50 ms", "in-service p99 ms", "p99 last 1024 ms", "wire p50 ms", "wire p99 ms",
                 "VLoc Hz", "fused ATE cm", "frames dropped", "odom lost", "CPU %", "RSS MB", "own RSS MB", "PSS MB",
                 "RSS growth %",
                 "GC max ms", "wall s", "behind real time s"],
                rows)
    if args.repeat > 1:  # does the benchmark reproduce its own figure: each run's p99s
        for m in args.modes:
            print(f"{names[m]}: in-service p99 per run " + ", ".join(f"{lat(r, 'p99_ms'):.2f}" for r in runs[m])
                  + " ms; wire p99 per run " + ", ".join(f"{r['wire_latency'].get('p99_ms', float('nan')):.2f}"
                                                       for r in runs[m]) + " ms")
    probe = f"SCHED_FIFO {args.probe_rt_priority}" if args.probe_rt_priority else "normal priority"
    print(f"in-service p99 over every fused pose of the run ('p99 last 1024': the status window earlier runs "
          f"reported); wire: the probe at {probe}.")
    print("in-service latency = odometry message dequeued -> fused pose handed to Zenoh. The sequential baseline\n"
          "handles each message quickly once it gets to it, but VLoc on every frame makes it fall behind the\n"
          "sensor stream: its poses are late by up to the 'behind real time' column.\n"
          "fused ATE: RMSE of the fused camera positions vs the recording's ground truth (no alignment).\n"
          "RSS = the service process and its children (recording reader, VLoc process) summed; own RSS = the\n"
          "service process alone; PSS = their proportional set sizes summed (shared pages counted once).")
    out: dict = {"seconds": args.seconds, "overrides": args.overrides, "alt_overrides": args.alt_overrides,
                 "probe_rt_priority": args.probe_rt_priority,
                 **results}
    if "realtime" in results and "sequential" in results:
        ratio = results["sequential"]["wall_s"] / results["realtime"]["wall_s"]
        print(f"wall time for {args.seconds:.0f} s of sensor data: sequential / threaded = {ratio:.1f}x")
        out["wall_ratio"] = ratio
    if "realtime" in results and "realtime+view" in results:
        off, on = results["realtime"], results["realtime+view"]
        cmp = {"fused_p99_ratio": lat(on, "p99_ms") / lat(off, "p99_ms"),
               "wire_p99_ratio": on["wire_latency"]["p99_ms"] / off["wire_latency"]["p99_ms"],
               "vloc_hz_ratio": on["vloc_hz"] / off["vloc_hz"], "view": on["view"], "rrd_mb": on["rrd_mb"]}
        print(f"view on / off: fused-pose p99 x{cmp['fused_p99_ratio']:.2f} in the service, "
              f"x{cmp['wire_p99_ratio']:.2f} on the wire; VLoc rate x{cmp['vloc_hz_ratio']:.2f}; "
              f"the view logged {on['view']['logged']}, dropped {on['view']['dropped']} of {on['view']['queued']}; "
              f".rrd {on['rrd_mb']:.1f} MB; RSS growth {off['rss']['growth_percent']:.1f} % off, "
              f"{on['rss']['growth_percent']:.1f} % on")
        out["view_comparison"] = cmp
    write_json("runtime" + ("_view" if "realtime+view" in results else ""), out)


if __name__ == "__main__":
    main()
