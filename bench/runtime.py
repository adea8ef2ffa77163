"""The onboard service on a recording in real time vs the sequential research-code baseline.

Runs the full runtime (map, ONNX models, GTSAM fusion, Zenoh) on the first `--seconds` of a
simulator query recording, once threaded (`runtime.mode=realtime`) and once sequential (one
thread, every message handled to completion in order, as the published research code does),
each in its own process so CPU time and peak RSS are its own. A separate Zenoh subscriber
process measures publish -> receive latency of the fused poses on the wire.

Reported: odometry-in -> pose-handed-to-Zenoh latency (p50/p99, inside the service), wire
latency (p50/p99, second process), VLoc rate, frames dropped, odometry lost, CPU %, peak RSS.

    litevloc demo            # once: makes out/demo/map and out/demo/query.mcap
    python bench/runtime.py [--seconds 30]
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _common import ROOT, print_table, write_json


def one_run(mode: str, rec: Path, map_dir: Path, seconds: float, endpoint: str, out: Path,
            overrides: list[str]) -> None:
    import dataclasses

    from litevloc.config import load_config
    from litevloc.hw.messages import Message
    from litevloc.hw.streams.mcap_io import McapSource
    from litevloc.runtime.app import build_app, with_endpoints

    cfg = load_config("default", [f"runtime.mode={mode}", *overrides])
    cfg = with_endpoints(cfg, [], [endpoint], None)
    cfg = dataclasses.replace(cfg, zenoh=dataclasses.replace(cfg.zenoh, listen=()))
    src = McapSource(rec, strict=False)
    n_frames = int(seconds * 15)

    def limited() -> Iterator[Message]:
        t_end = None
        for m in src:
            t_end = m.t_ns + int(seconds * 1e9) if t_end is None else t_end
            if m.t_ns > t_end:
                break
            yield m

    app = build_app(cfg, map_dir, limited(), 1.0)
    ru0, t0 = resource.getrusage(resource.RUSAGE_SELF), time.perf_counter()
    res = app.service.run()
    wall = time.perf_counter() - t0
    ru1 = resource.getrusage(resource.RUSAGE_SELF)
    app.close()
    st = res.status
    c = st.get("counters", {})
    out.write_text(json.dumps({
        "mode": mode, "ok": res.ok, "reason": res.reason, "wall_s": wall, "frames": n_frames,
        "cpu_percent": 100 * ((ru1.ru_utime - ru0.ru_utime) + (ru1.ru_stime - ru0.ru_stime)) / wall,
        "peak_rss_mb": ru1.ru_maxrss / 1024, "counters": c, "frames_dropped": st.get("frames_dropped"),
        "vloc_hz": c.get("vloc_calls", 0) / seconds,
        "latency": st.get("latency", {}).get("odometry_to_publish", {}),
        "odometry_lost": c.get("odometry_in", 0) - c.get("odometry_fused", 0),
    }, default=float))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--rec", type=Path, default=ROOT / "out/demo/query.mcap")
    ap.add_argument("--map", type=Path, default=ROOT / "out/demo/map")
    ap.add_argument("--seconds", type=float, default=30.0)
    ap.add_argument("--modes", nargs="+", default=["realtime", "sequential"], choices=["realtime", "sequential"])
    ap.add_argument("--set", dest="overrides", action="append", default=[], help="config override, e.g. "
                    "models.intra_op_threads=1")
    ap.add_argument("--one", nargs=3, metavar=("MODE", "ENDPOINT", "OUT"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.one:
        one_run(args.one[0], args.rec, args.map, args.seconds, args.one[1], Path(args.one[2]), args.overrides)
        return
    if not args.rec.is_file() or not args.map.is_dir():
        raise SystemExit(f"needs {args.rec} and {args.map}: run `litevloc demo` first")
    sys.path.insert(0, str(ROOT / "tests" / "runtime"))
    from zenoh_helpers import finish_probe, free_port, start_probe

    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        for mode in args.modes:
            ep = f"tcp/127.0.0.1:{free_port()}"
            probe_out, run_out = Path(tmp) / f"probe_{mode}.json", Path(tmp) / f"run_{mode}.json"
            proc = start_probe(ep, probe_out, "pose", {}, timeout=args.seconds * 20 + 120, idle=15.0, listen=True)
            subprocess.run([sys.executable, __file__, "--rec", str(args.rec), "--map", str(args.map), "--seconds",
                            str(args.seconds), *[a for o in args.overrides for a in ("--set", o)],
                            "--one", mode, ep, str(run_out)], check=True)
            wire = finish_probe(proc, probe_out, timeout=60)["topics"]["pose"]
            r = json.loads(run_out.read_text())
            r["wire_latency"] = wire["latency"]
            r["poses_received"] = wire["count"]
            results[mode] = r

    def lat(r: dict, k: str) -> float:
        return float(r["latency"].get(k) or float("nan"))

    rows = []
    names = {"realtime": "threaded runtime (realtime)", "sequential": "sequential baseline"}
    for name, r in ((names[m], results[m]) for m in args.modes):
        r["lag_s"] = max(r["wall_s"] - args.seconds, 0.0)
        rows.append([name, lat(r, "median_ms"), lat(r, "p99_ms"), r["wire_latency"].get("median_ms", float("nan")),
                     r["wire_latency"].get("p99_ms", float("nan")), r["vloc_hz"], r["frames_dropped"],
                     r["odometry_lost"], r["cpu_percent"], r["peak_rss_mb"], r["wall_s"], r["lag_s"]])
    print_table(f"Onboard service on {args.seconds:.0f} s of {args.rec.name} (15 Hz camera, 200 Hz odometry), 2 CPUs",
                ["mode", "in-service p50 ms", "in-service p99 ms", "wire p50 ms", "wire p99 ms", "VLoc Hz",
                 "frames dropped", "odom lost", "CPU %", "RSS MB", "wall s", "behind real time s"], rows)
    print("in-service latency = odometry message dequeued -> fused pose handed to Zenoh. The sequential baseline\n"
          "handles each message quickly once it gets to it, but VLoc on every frame makes it fall behind the\n"
          "sensor stream: its poses are late by up to the 'behind real time' column.")
    out: dict = {"seconds": args.seconds, "overrides": args.overrides, **results}
    if "realtime" in results and "sequential" in results:
        ratio = results["sequential"]["wall_s"] / results["realtime"]["wall_s"]
        print(f"wall time for {args.seconds:.0f} s of sensor data: sequential / threaded = {ratio:.1f}x")
        out["wall_ratio"] = ratio
    write_json("runtime", out)


if __name__ == "__main__":
    main()
