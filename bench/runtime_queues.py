"""Runtime plumbing costs: queue operations, thread hand-off, and Zenoh wire latency.

    .venv/bin/python bench/runtime_queues.py [--seconds 10] [--rate 200]

1. Queue op cost (ns per put+get, one thread): our `BoundedFifo` / `LatestMailbox` vs
   `queue.Queue` (the lock-per-operation baseline) and a bare `collections.deque`.
2. Thread hand-off latency (put in one thread -> a blocked consumer has it), median/p99:
   `BoundedFifo.get` vs `queue.Queue.get`, at 200 Hz.
3. Zenoh over loopback TCP, across processes: nav_msgs/Odometry (fused pose) published
   at `--rate` Hz by `LiteVLocPublisher.publish_pose` here, received and CDR-decoded by
   `python -m litevloc.runtime.transport.probe` in another process. Latency = receive time - send
   time (attachment; CLOCK_MONOTONIC is machine-wide), plus the message build +
   serialisation cost on the publisher side.
Prints a table; JSON in out/bench/runtime_queues.json.
"""

from __future__ import annotations

import argparse
import json
import queue
import subprocess
import sys
import tempfile
import threading
import time
from collections import deque
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import print_table, write_json

from litevloc.base.geometry import make_T, so3_exp
from litevloc.base.stats import percentiles_ms
from litevloc.config.schema import ZenohConfig
from litevloc.hw import ros_msgs
from litevloc.runtime.metrics import now_ns
from litevloc.runtime.service.queues import BoundedFifo, LatestMailbox
from litevloc.runtime.transport.bus import Bus, LiteVLocPublisher

PROBE = "litevloc.runtime.transport.probe"


def op_cost(n: int = 200_000) -> dict[str, float]:
    """Median over 5 repeats of ns per (put + get) pair in one thread."""
    def run(put, get) -> float:  # type: ignore[no-untyped-def]
        t = []
        for _ in range(5):
            t0 = time.perf_counter_ns()
            for i in range(n):
                put(i)
                get()
            t.append((time.perf_counter_ns() - t0) / n)
        return float(np.median(t))

    fifo: BoundedFifo[int] = BoundedFifo("b", 1_000_000)
    mb: LatestMailbox[int] = LatestMailbox("m")
    qq: queue.Queue[int] = queue.Queue()
    dq: deque[int] = deque()
    return {
        "deque (bare)": run(dq.append, dq.popleft),
        "BoundedFifo": run(fifo.put, fifo.get_nowait),
        "LatestMailbox": run(mb.put, mb.get_nowait),
        "queue.Queue": run(qq.put, qq.get_nowait),
    }


def handoff(kind: str, n: int = 600, period_s: float = 0.005) -> dict[str, float]:
    """Producer at 1/period_s Hz stamps items; a consumer blocked in get() measures arrival delay."""
    lat: list[float] = []
    if kind == "BoundedFifo":
        q: BoundedFifo[int] = BoundedFifo("h", 10_000)
        get = lambda: q.get(2.0)  # noqa: E731
        put = q.put
    else:
        qq: queue.Queue[int] = queue.Queue()
        get = lambda: qq.get(timeout=2.0)  # noqa: E731
        put = qq.put

    def consumer() -> None:
        for _ in range(n):
            t = get()
            lat.append((now_ns() - t) * 1e-6)

    th = threading.Thread(target=consumer)
    th.start()
    t_next = time.monotonic()
    for _ in range(n):
        put(now_ns())
        t_next += period_s
        time.sleep(max(0.0, t_next - time.monotonic()))
    th.join(10)
    return percentiles_ms(lat)


def zenoh_latency(seconds: float, rate: float) -> dict[str, object]:
    sock = __import__("socket").socket()
    sock.bind(("127.0.0.1", 0))
    port = sock.getsockname()[1]
    sock.close()
    ep = f"tcp/127.0.0.1:{port}"
    n = int(seconds * rate)
    out = Path(tempfile.mkdtemp()) / "probe.json"
    build: list[float] = []
    with Bus(ZenohConfig(listen=(ep,))) as bus:
        pub = LiteVLocPublisher(bus)
        proc = subprocess.Popen(
            [sys.executable, "-m", "litevloc.runtime.transport.probe", "--connect", ep, "--topics", "pose",
             "--count", f"pose={n}", "--timeout", str(seconds + 30), "--json", str(out)],
            stdout=subprocess.PIPE, text=True)
        assert proc.stdout is not None
        assert proc.stdout.readline().strip() == "READY", "probe did not connect"
        time.sleep(0.5)
        rng = np.random.default_rng(0)
        Ts = [make_T(so3_exp(rng.normal(size=3)), rng.normal(size=3)) for _ in range(64)]
        cov = np.eye(6) * 0.01
        t_next = time.monotonic()
        for i in range(n):
            t0 = now_ns()
            pub.publish_pose(1_000_000_000 + i * int(1e9 / rate), Ts[i % 64], cov)
            build.append((now_ns() - t0) * 1e-6)
            t_next += 1.0 / rate
            time.sleep(max(0.0, t_next - time.monotonic()))
        proc.wait(timeout=60)
        put_ms = pub.pubs["pose"].put_latency.summary()
    res = json.loads(out.read_text())["topics"]["pose"]
    return {"sent": n, "received": res["count"], "decode_errors": res["decode_errors"],
            "over_1ms": res["over_1ms"], "over_5ms": res["over_5ms"],
            "wire": res["latency"], "publish_call": percentiles_ms(build), "zenoh_put": put_ms}


def service_e2e(switch_interval_s: float, vloc_ms: float, seconds: float = 6.0) -> dict[str, object]:
    """Service in realtime mode, 200 Hz odometry + 30 Hz frames from a synthetic recording, a
    VLoc stand-in that HOLDS the GIL for `vloc_ms` (pure-Python busy loop: the worst case; the
    real ORT/OpenCV calls release it), fake fusion, no-op publisher. Returns the service's own
    odometry-enqueued -> pose-handed-to-publisher latency."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from litevloc.base.params.drift import T_BASE_CAMERA_OPTICAL
    from litevloc.config.schema import RuntimeConfig
    from tests.runtime.fakes import (
        T_MAP_ODOM_TRUE,
        FakeFusion,
        FakePublisher,
        Result,
        SyntheticSource,
        T_odom_base_at,
        make_service,
    )

    def vloc(frame, prior):  # type: ignore[no-untyped-def]
        t0 = time.perf_counter()
        x = 0
        while (time.perf_counter() - t0) * 1e3 < vloc_ms:
            x += 1
        T = T_MAP_ODOM_TRUE @ T_odom_base_at(frame.t_ns) @ T_BASE_CAMERA_OPTICAL
        return Result(frame.t_ns, True, "ok", T, np.eye(6) * 1e-4)

    old = sys.getswitchinterval()
    fusion = FakeFusion()
    svc = make_service(SyntheticSource(seconds=seconds, odom_hz=200, frame_hz=30), vloc, fusion, FakePublisher(),
                       RuntimeConfig(gil_switch_interval_s=switch_interval_s), rate=1.0)
    try:
        res = svc.run(timeout_s=seconds + 30)
    finally:
        sys.setswitchinterval(old)
    st = res.status
    return {"odometry_to_publish": st["latency"]["odometry_to_publish"], "vloc_calls": st["counters"]["vloc_calls"],
            "frames_dropped": st["frames_dropped"], "odometry_lost": st["counters"]["odometry_in"]
            - st["counters"]["odometry_fused"]}


def _popen_ready(cmd: list[str]) -> subprocess.Popen[str]:
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None
    line = proc.stdout.readline().strip()
    assert line == "READY", f"{cmd[3:5]} did not get ready: {line!r}"
    return proc


def service_wire_e2e(switch_interval_s: float, vloc_ms: float, seconds: float = 8.0,
                     inline: bool = False) -> dict[str, object]:
    """Three processes: a robot stand-in publishing 200 Hz odometry over Zenoh (stamped with
    the monotonic clock), the service here (odometry_input zenoh, 30 Hz synthetic frames, a
    GIL-holding `vloc_ms` VLoc stand-in, fake fusion, the real Zenoh publisher), and the probe
    measuring pose receive time - odometry stamp: odometry-in -> pose-out on the wire."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from litevloc.base.params.drift import T_BASE_CAMERA_OPTICAL
    from litevloc.config.schema import RuntimeConfig
    from litevloc.hw.odometry import OdometryReceiver
    from tests.runtime.fakes import T_MAP_ODOM_TRUE, FakeFusion, Result, SyntheticSource, T_odom_base_at, make_service

    def vloc(frame, prior):  # type: ignore[no-untyped-def]
        t0 = time.perf_counter()
        x = 0
        while (time.perf_counter() - t0) * 1e3 < vloc_ms:
            x += 1
        T = T_MAP_ODOM_TRUE @ T_odom_base_at(frame.t_ns) @ T_BASE_CAMERA_OPTICAL
        return Result(frame.t_ns, True, "ok", T, np.eye(6) * 1e-4)

    sock = __import__("socket").socket()
    sock.bind(("127.0.0.1", 0))
    port = sock.getsockname()[1]
    sock.close()
    ep = f"tcp/127.0.0.1:{port}"
    out = Path(tempfile.mkdtemp()) / "probe.json"
    old = sys.getswitchinterval()
    params = RuntimeConfig(odometry_input="zenoh", odometry_key="robot/odom", gil_switch_interval_s=switch_interval_s,
                           publish_inline=inline)
    with Bus(ZenohConfig(listen=(ep,))) as bus:
        pub = LiteVLocPublisher(bus)
        probe = _popen_ready([sys.executable, "-m", PROBE, "--connect", ep, "--topics", "pose",
                              "--stamp-latency", "--idle", "2", "--timeout", str(seconds + 30), "--json", str(out)])
        fusion = FakeFusion()
        svc = make_service(SyntheticSource(seconds=seconds, odom_hz=10, frame_hz=30), vloc, fusion, pub, params,
                           rate=1.0,
                           odometry_receiver=lambda sink: OdometryReceiver(bus.session, "robot/odom", sink))
        robot = _popen_ready([sys.executable, "-m", PROBE, "--connect", ep, "--send-odometry",
                              "robot/odom", "--rate", "200", "--seconds", str(seconds - 1.0)])
        try:
            res = svc.run(timeout_s=seconds + 30)
        finally:
            sys.setswitchinterval(old)
        robot.wait(timeout=30)
        probe.wait(timeout=60)
    pose = json.loads(out.read_text())["topics"]["pose"]
    st = res.status
    return {"e2e_wire": pose["stamp_latency"], "received": pose["count"],
            "odometry_accepted": st["odometry"]["accepted"], "odometry_fused": st["counters"]["odometry_fused"],
            "poses_published": st["counters"]["poses_published"], "vloc_calls": st["counters"]["vloc_calls"],
            "in_service": st["latency"]["odometry_to_publish"]}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--rate", type=float, default=200.0)
    args = ap.parse_args()

    ops = op_cost()
    base = ops["queue.Queue"]
    print_table("queue op cost, one thread (put + get)", ["queue", "ns/pair", "vs queue.Queue"],
                [[k, v, v / base] for k, v in ops.items()])
    hand = {k: handoff(k) for k in ("BoundedFifo", "queue.Queue")}
    print_table("thread hand-off at 200 Hz (put -> blocked consumer has it)", ["queue", "median ms", "p99 ms"],
                [[k, v["median_ms"], v["p99_ms"]] for k, v in hand.items()])
    z = zenoh_latency(args.seconds, args.rate)
    wire, call = z["wire"], z["publish_call"]
    assert isinstance(wire, dict) and isinstance(call, dict)
    print_table(f"Zenoh loopback TCP, nav_msgs/Odometry at {args.rate:g} Hz, other process "
                f"({z['received']}/{z['sent']} received, {z['decode_errors']} decode errors, "
                f"{z['over_1ms']} over 1 ms, {z['over_5ms']} over 5 ms)",
                ["measure", "median ms", "p90 ms", "p99 ms", "max ms"],
                [["send -> receive (wire)", wire["median_ms"], wire["p90_ms"], wire["p99_ms"], wire["max_ms"]],
                 ["publish_pose call (build+CDR+put)", call["median_ms"], call["p90_ms"], call["p99_ms"],
                  call["max_ms"]]])
    e2e = {f"{si * 1e3:g} ms": service_e2e(si, 300.0) for si in (0.005, 0.0005)}
    rows = []
    for k, v in e2e.items():
        lat = v["odometry_to_publish"]
        assert isinstance(lat, dict)
        rows.append([k, lat["median_ms"], lat["p99_ms"], lat["max_ms"], v["vloc_calls"], v["frames_dropped"],
                     v["odometry_lost"]])
    print_table("service, 200 Hz odometry, GIL-holding 300 ms VLoc stand-in: odometry in -> pose to publisher",
                ["GIL switch interval", "median ms", "p99 ms", "max ms", "vloc calls", "frames dropped",
                 "odometry lost"], rows)
    wire = {f"{si * 1e3:g} ms, VLoc {v:g} ms{', inline publish' if inl else ''}": service_wire_e2e(si, v, inline=inl)
            for si, v, inl in ((0.005, 300.0, False), (0.0005, 300.0, False), (0.0005, 300.0, True),
                               (0.0005, 0.0, False))}
    rows = []
    for k, v in wire.items():
        lat = v["e2e_wire"]
        assert isinstance(lat, dict)
        rows.append([k, lat["median_ms"], lat["p99_ms"], lat["max_ms"], v["received"], v["odometry_accepted"],
                     v["vloc_calls"]])
    print_table("3 processes: robot odometry 200 Hz -> Zenoh -> service (GIL-holding 300 ms VLoc) -> Zenoh -> probe",
                ["GIL switch interval, VLoc stand-in", "median ms", "p99 ms", "max ms", "poses received", "odometry in",
                 "vloc calls"], rows)
    write_json("runtime_queues", {"queue_ns_per_pair": ops, "handoff_ms": hand, "zenoh": z, "service_e2e": e2e,
                                  "service_wire_e2e": wire,
                                  "cdr_message": ros_msgs.ODOMETRY})
    return 0


if __name__ == "__main__":
    sys.exit(main())
