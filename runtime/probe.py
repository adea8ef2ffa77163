"""A separate-process Zenoh subscriber that decodes LiteVLoc's topics (tests, benchmarks, debugging).

    python -m litevloc.runtime.probe --connect tcp/127.0.0.1:7447 --topics pose,status \
        --count pose=1000 --timeout 20 --json out.json

It connects (peer mode, no listen, no scouting) to the given endpoint, subscribes to
`<namespace>/litevloc/<topic>` for each topic, decodes every payload with the ROS 2 CDR
decoder (`hw.ros_msgs.deserialize`, rosbags), and records per topic: message count,
decode errors, wire latency (receive time - the publisher's send time in the
attachment, same-machine monotonic clock), and the decoded content (poses as
[t_ns, x, y, z, qx, qy, qz, qw], status as parsed JSON). It prints `READY` on stdout
once subscribed and connected, so a test can start publishing, and stops when every
`--count` is reached, after `--idle` seconds without messages, or at `--timeout`.
Exit code 0 when every count was reached, 3 on timeout.
"""

from __future__ import annotations

import argparse
import json
import sys
import threading
import time
from typing import Any

import numpy as np


def _pose_row(t_ns: int, T: np.ndarray) -> list[float]:
    from litevloc.pipelines.geometry import matrix_to_quat_xyzw

    q = matrix_to_quat_xyzw(T[:3, :3])
    return [float(t_ns), *map(float, T[:3, 3]), *map(float, q)]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m litevloc.runtime.probe", description=__doc__.split("\n")[0])
    ap.add_argument("--connect", action="append", required=True, help="endpoint, e.g. tcp/127.0.0.1:7447")
    ap.add_argument("--namespace", default="")
    ap.add_argument("--topics", default="pose,vloc,map_to_odom,status")
    ap.add_argument("--count", action="append", default=[], metavar="TOPIC=N", help="stop after N messages")
    ap.add_argument("--timeout", type=float, default=30.0)
    ap.add_argument("--idle", type=float, default=0.0, help="stop after this long without messages (0 = never)")
    ap.add_argument("--json", default=None, help="write the results here (default: stdout)")
    ap.add_argument("--keep", action="store_true", help="keep decoded poses/status in the JSON")
    args = ap.parse_args(argv)

    from litevloc.config.schema import ZenohConfig
    from litevloc.hw import ros_msgs
    from litevloc.runtime.bus import TOPICS, Bus, send_time_ns, topic_key, warm_codecs
    from litevloc.runtime.metrics import now_ns, percentiles_ms

    topics = [t.strip() for t in args.topics.split(",") if t.strip()]
    for t in topics:
        if t not in TOPICS:
            ap.error(f"unknown topic {t!r}; known: {sorted(TOPICS)}")
    want = {k: int(v) for k, v in (c.split("=", 1) for c in args.count)}
    cfg = ZenohConfig(mode="peer", listen=(), connect=tuple(args.connect), namespace=args.namespace,
                      connect_timeout_s=min(args.timeout, 10.0))
    warm_codecs()
    bus = Bus(cfg)
    res: dict[str, dict[str, Any]] = {t: {"count": 0, "decode_errors": 0, "lat_ms": [], "data": []} for t in topics}
    lock = threading.Lock()
    last_rx = [time.monotonic()]
    done = threading.Event()

    def make_cb(topic: str) -> Any:
        typename = TOPICS[topic][1]

        def cb(sample: Any) -> None:
            t_rx = now_ns()
            sent = send_time_ns(sample)
            r = res[topic]
            try:
                msg = ros_msgs.deserialize(sample.payload.to_bytes(), typename)
            except ros_msgs.MessageDecodeError:
                with lock:
                    r["decode_errors"] += 1
                return
            item: Any = None
            if args.keep:
                if topic == "pose":
                    t_ns, T, _ = ros_msgs.odometry_to_matrix(msg)
                    item = _pose_row(t_ns, T)
                elif topic == "vloc":
                    item = _pose_row(ros_msgs.stamp_ns(msg.header), ros_msgs.pose_to_matrix(msg.pose.pose))
                elif topic == "map_to_odom":
                    tr = msg.transform
                    item = [ros_msgs.stamp_ns(msg.header), tr.translation.x, tr.translation.y, tr.translation.z,
                            tr.rotation.x, tr.rotation.y, tr.rotation.z, tr.rotation.w]
                else:
                    item = json.loads(msg.data)
            with lock:
                r["count"] += 1
                if sent is not None:
                    r["lat_ms"].append((t_rx - sent) * 1e-6)
                if item is not None:
                    r["data"].append(item)
                last_rx[0] = time.monotonic()
                if want and all(res[k]["count"] >= n for k, n in want.items() if k in res):
                    done.set()

        return cb

    subs = [bus.subscribe(topic_key(args.namespace, t), make_cb(t)) for t in topics]
    t_end = time.monotonic() + args.timeout
    while not bus.connectivity()["connected"] and time.monotonic() < t_end:
        time.sleep(0.01)
    print("READY" if bus.connectivity()["connected"] else "NOT-CONNECTED", flush=True)
    last_rx[0] = time.monotonic()
    while not done.is_set() and time.monotonic() < t_end:
        if args.idle > 0 and time.monotonic() - last_rx[0] > args.idle:
            break
        done.wait(0.05)
    for s in subs:
        s.undeclare()
    bus.close()
    with lock:
        out = {
            t: {"count": r["count"], "decode_errors": r["decode_errors"], "latency": percentiles_ms(r["lat_ms"]),
                "over_1ms": int(np.sum(np.asarray(r["lat_ms"]) > 1.0)),
                "over_5ms": int(np.sum(np.asarray(r["lat_ms"]) > 5.0)),
                **({"data": r["data"]} if args.keep else {})}
            for t, r in res.items()
        }
    text = json.dumps({"topics": out, "completed": done.is_set()}, default=float)
    if args.json:
        with open(args.json, "w") as f:
            f.write(text)
    else:
        print(text, flush=True)
    return 0 if (done.is_set() or not want) else 3


if __name__ == "__main__":
    sys.exit(main())
