"""A separate-process Zenoh subscriber that decodes LiteVLoc's topics (tests, benchmarks, debugging).

    python -m litevloc.runtime.transport.probe --connect tcp/127.0.0.1:7447 --topics pose,status \
        --count pose=1000 --timeout 20 --json out.json

It connects (peer mode, no listen, no scouting) to the given endpoint, subscribes to
`<namespace>/litevloc/<topic>` for each topic, decodes every payload with the ROS 2 CDR
decoder (`hw.ros_msgs.deserialize`, rosbags), and records per topic: message count,
decode errors, wire latency (receive time - the publisher's send time in the
attachment, same-machine monotonic clock), and the decoded content (poses as
[t_ns, x, y, z, qx, qy, qz, qw], status as parsed JSON). It prints `READY` on stdout
once subscribed and connected, so a test can start publishing, and stops when every
`--count` is reached, after `--idle` seconds without messages once the first one arrived (a
publisher that is slow to start is waited for up to `--timeout`), or at `--timeout`.
Exit code 0 when every count was reached, 3 on timeout.

`--stamp-latency` also records, for `pose`, receive time - header stamp: end-to-end
latency when the odometry source stamps with `time.monotonic_ns()` (as
`--send-odometry` does), because a fused pose carries its odometry message's stamp.

Sender mode (a robot stand-in): `--send-odometry KEY --rate 200 --seconds 10` publishes
nav_msgs/Odometry on KEY, stamped with `time.monotonic_ns()`, prints READY when
connected, and exits after `--seconds`.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import threading
import time
from typing import Any

import numpy as np


def _pose_row(t_ns: int, T: np.ndarray) -> list[float]:
    from litevloc.base.geometry import matrix_to_quat_xyzw

    q = matrix_to_quat_xyzw(T[:3, :3])
    return [float(t_ns), *map(float, T[:3, 3]), *map(float, q)]


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="python -m litevloc.runtime.transport.probe", description=__doc__.split("\n")[0])
    ap.add_argument("--connect", action="append", default=[], help="endpoint, e.g. tcp/127.0.0.1:7447")
    ap.add_argument("--listen", action="append", default=[], help="listen here instead (the service connects)")
    ap.add_argument("--namespace", default="")
    ap.add_argument("--ros2", choices=("bridge", "rmw_zenoh"), default="bridge", help="key naming (zenoh.ros2)")
    ap.add_argument("--ros2-distro", choices=("jazzy", "humble", "auto"), default="jazzy",
                    help="rmw_zenoh: the robot's ROS 2 (zenoh.ros2_distro)")
    ap.add_argument("--topics", default="pose,vloc,map_to_odom,status")
    ap.add_argument("--count", action="append", default=[], metavar="TOPIC=N", help="stop after N messages")
    ap.add_argument("--timeout", type=float, default=30.0)
    ap.add_argument("--idle", type=float, default=0.0,
                    help="stop after this long without messages, counted from the first one (0 = never)")
    ap.add_argument("--json", default=None, help="write the results here (default: stdout)")
    ap.add_argument("--keep", action="store_true", help="keep decoded poses/status in the JSON")
    ap.add_argument("--stamp-latency", action="store_true", help="pose: also receive time - header stamp")
    ap.add_argument("--rt-priority", type=int, default=0, metavar="N",
                    help="receive in SCHED_FIFO at N (1-99; 0 = normal): the probe's Zenoh threads inherit it, so "
                         "the wire latency is the transport's, not the probe's wait for a core on a loaded machine")
    ap.add_argument("--send-odometry", default=None, metavar="KEY", help="sender mode: publish odometry on KEY")
    ap.add_argument("--rate", type=float, default=200.0, help="sender mode: Hz")
    ap.add_argument("--seconds", type=float, default=10.0, help="sender mode: duration")
    return ap


def _kept_item(topic: str, msg: Any) -> Any:
    """What `--keep` stores of one message: a pose row (t_ns, x, y, z, qx, qy, qz, qw) for the
    pose topics and the transform, the decoded JSON for the status."""
    from litevloc.hw import ros_msgs

    if topic == "pose":
        t_ns, T, _ = ros_msgs.odometry_to_matrix(msg)
        return _pose_row(t_ns, T)
    if topic == "vloc":
        return _pose_row(ros_msgs.stamp_ns(msg.header), ros_msgs.pose_to_matrix(msg.pose.pose))
    if topic == "map_to_odom":
        tr = msg.transform
        return [ros_msgs.stamp_ns(msg.header), tr.translation.x, tr.translation.y, tr.translation.z,
                tr.rotation.x, tr.rotation.y, tr.rotation.z, tr.rotation.w]
    return json.loads(msg.data)


def main(argv: list[str] | None = None) -> int:
    ap = _parser()
    args = ap.parse_args(argv)
    if not args.connect and not args.listen:
        ap.error("give --connect ENDPOINT or --listen ENDPOINT")
    if args.send_odometry:
        return _send(args)
    from litevloc.runtime.transport.bus import TOPICS

    topics = [t.strip() for t in args.topics.split(",") if t.strip()]
    for t in topics:
        if t not in TOPICS:
            ap.error(f"unknown topic {t!r}; known: {sorted(TOPICS)}")
    return _receive(args, topics)


class _Tally:
    """What arrived per topic (counts, decode errors, latencies, kept items), filled by the
    subscriber callbacks; `done` is set once every `want` count is reached."""

    def __init__(self, topics: list[str], want: dict[str, int], args: argparse.Namespace) -> None:
        self.res: dict[str, dict[str, Any]] = {
            t: {"count": 0, "decode_errors": 0, "lat_ms": [], "data": [], "stamp_ms": []} for t in topics}
        self.want, self.args = want, args
        self.lock = threading.Lock()
        self.last_rx = time.monotonic()
        self.done = threading.Event()

    def callback(self, topic: str) -> Any:
        from litevloc.hw import ros_msgs
        from litevloc.runtime.metrics import now_ns
        from litevloc.runtime.transport.bus import TOPICS, wire_latency_ns

        typename, args = TOPICS[topic][1], self.args

        def cb(sample: Any) -> None:
            t_rx = now_ns()
            wire_ns = wire_latency_ns(sample)
            r = self.res[topic]
            try:
                msg = ros_msgs.deserialize(sample.payload.to_bytes(), typename)
            except ros_msgs.MessageDecodeError:
                with self.lock:
                    r["decode_errors"] += 1
                return
            item = _kept_item(topic, msg) if args.keep else None
            if args.stamp_latency and topic == "pose":
                r["stamp_ms"].append((t_rx - ros_msgs.stamp_ns(msg.header)) * 1e-6)
            with self.lock:
                r["count"] += 1
                if wire_ns is not None:
                    r["lat_ms"].append(wire_ns * 1e-6)
                if item is not None:
                    r["data"].append(item)
                self.last_rx = time.monotonic()
                if self.want and all(self.res[k]["count"] >= n for k, n in self.want.items() if k in self.res):
                    self.done.set()

        return cb

    def wait(self, t_end: float, idle_s: float) -> str:
        """Until the counts, `idle_s` without messages once one arrived, or `t_end`; which of them."""
        while time.monotonic() < t_end:
            if self.done.is_set():
                return "count"
            got_any = any(r["count"] or r["decode_errors"] for r in self.res.values())
            if idle_s > 0 and got_any and time.monotonic() - self.last_rx > idle_s:
                return "idle"
            self.done.wait(0.05)
        return "timeout"

    def summary(self) -> dict[str, Any]:
        from litevloc.base.stats import percentiles_ms

        args = self.args
        with self.lock:
            return {
                t: {"count": r["count"], "decode_errors": r["decode_errors"], "latency": percentiles_ms(r["lat_ms"]),
                    "over_1ms": int(np.sum(np.asarray(r["lat_ms"]) > 1.0)),
                    "over_5ms": int(np.sum(np.asarray(r["lat_ms"]) > 5.0)),
                    **({"stamp_latency": percentiles_ms(r["stamp_ms"])} if args.stamp_latency else {}),
                    **({"data": r["data"]} if args.keep else {})}
                for t, r in self.res.items()
            }


def _receive(args: argparse.Namespace, topics: list[str]) -> int:
    from litevloc.config.schema import ZenohConfig
    from litevloc.runtime.transport.bus import TOPICS, Bus, warm_codecs

    want = {k: int(v) for k, v in (c.split("=", 1) for c in args.count)}
    cfg = ZenohConfig(mode="peer", listen=tuple(args.listen), connect=tuple(args.connect), namespace=args.namespace,
                      connect_timeout_s=min(args.timeout, 10.0), ros2=args.ros2,
                      ros2_distro=args.ros2_distro, node_name="litevloc_probe")
    warm_codecs()
    if args.rt_priority > 0:  # before the session exists: its threads inherit the policy
        _realtime(args.rt_priority)
    bus = Bus(cfg)
    tally = _Tally(topics, want, args)
    subs = [bus.subscribe_topic(t, TOPICS[t][1], tally.callback(t)) for t in topics]
    t_end = time.monotonic() + args.timeout
    if args.listen:  # listening: ready as soon as the subscribers exist; the service connects to us
        print("READY", flush=True)
    else:
        while not bus.connectivity()["connected"] and time.monotonic() < t_end:
            time.sleep(0.01)
        print("READY" if bus.connectivity()["connected"] else "NOT-CONNECTED", flush=True)
    ended = tally.wait(t_end, args.idle)  # what ended the probe: the counts asked for, the idle limit or the timeout
    for s in subs:
        s.undeclare()
    bus.close()
    text = json.dumps({"topics": tally.summary(), "completed": tally.done.is_set(), "ended": ended}, default=float)
    if args.json:
        with open(args.json, "w") as f:
            f.write(text)
    else:
        print(text, flush=True)
    return 0 if (tally.done.is_set() or not want) else 3


def _realtime(priority: int) -> None:
    """This process's calling thread (and the threads it starts) in SCHED_FIFO at `priority`;
    a probe without the privilege exits 2 naming it (its figures would not be the asked-for ones)."""
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except (OSError, AttributeError) as exc:
        print(f"probe: SCHED_FIFO {priority} not permitted ({exc}); run without --rt-priority or give CAP_SYS_NICE",
              file=sys.stderr)
        raise SystemExit(2) from exc


def _send(args: argparse.Namespace) -> int:
    from litevloc.base.geometry import make_T, so3_exp
    from litevloc.config.schema import ZenohConfig
    from litevloc.hw.messages import Odometry
    from litevloc.hw.odometry import OdometrySender
    from litevloc.runtime.transport.bus import Bus, warm_codecs

    warm_codecs()
    bus = Bus(ZenohConfig(mode="peer", listen=(), connect=tuple(args.connect), connect_timeout_s=10.0))
    tx = OdometrySender(bus.session, args.send_odometry)
    print("READY", flush=True)
    n = int(args.seconds * args.rate)
    t_next = time.monotonic()
    for i in range(n):
        s = i / args.rate
        T = make_T(so3_exp(np.array([0.0, 0.0, 0.3 * s])), np.array([0.5 * s, 0.0, 0.0]))
        tx.send(Odometry(time.monotonic_ns(), T))
        t_next += 1.0 / args.rate
        time.sleep(max(0.0, t_next - time.monotonic()))
    tx.close()
    bus.close()
    print(json.dumps({"sent": n}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
