"""`litevloc plan`: the planner service (image goals -> subgoals over Zenoh).

    litevloc plan --config CFG [--map MAP] [--listen EP] [--connect EP] [--namespace NS]
                  [--duration S] [--json PATH]

Subscribes to the runtime's fused pose and to goal images (`litevloc goal send`),
publishes subgoals and status; see `runtime.planner.node` for the topics.
"""

from __future__ import annotations

import argparse
import signal
import threading
from pathlib import Path

from litevloc.cli.common import add_config_args, add_json_arg, config_of
from litevloc.cli.main import UserError
from litevloc.pipelines.topomap.io import load_map
from litevloc.runtime.tools.outputs import write_json


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("plan", help="planner service: goal images -> subgoals on the map (Zenoh)")
    add_config_args(p)
    p.add_argument("--map", type=Path, default=None, help="map folder (default: the config's `map`)")
    p.add_argument("--listen", action="append", default=[], metavar="ENDPOINT", help="e.g. tcp/127.0.0.1:7448")
    p.add_argument("--connect", action="append", default=[], metavar="ENDPOINT",
                   help="the runtime's endpoint, e.g. tcp/127.0.0.1:7447")
    p.add_argument("--namespace", default=None, help="key-expression prefix, e.g. robot1")
    p.add_argument("--duration", type=float, default=None, metavar="S", help="stop after S seconds")
    add_json_arg(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from litevloc.runtime.planner.node import PlannerService, build_planner
    from litevloc.runtime.service.app import with_endpoints
    from litevloc.runtime.transport.bus import Bus

    cfg = with_endpoints(config_of(args), args.listen, args.connect, args.namespace)
    map_path = args.map or (Path(cfg.map) if cfg.map else None)
    if map_path is None:
        raise UserError("no map: give --map or set `map` in the config")
    planner = build_planner(cfg, load_map(map_path))
    bus = Bus(cfg.zenoh, node_name=f"{cfg.zenoh.node_name}_planner")
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    svc = PlannerService(bus, planner, cfg.zenoh.goal_pose, cfg.zenoh.tf).start()
    print(f"planner: map {map_path} ({planner.map.n_nodes} nodes), listen {list(cfg.zenoh.listen)}, "
          f"connect {list(cfg.zenoh.connect)}; waiting for goals on "
          f"{bus.key('litevloc/goal_image', 'sensor_msgs/msg/CompressedImage')}", flush=True)
    try:
        stop.wait(args.duration)
    finally:
        svc.close()
        bus.close()
    write_json(args.json, {"counters": svc.counters, "status": planner.status.as_dict()})
    print(f"planner: stopped; {svc.counters}")
    return 0
