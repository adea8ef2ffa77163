"""`litevloc goal send IMG... [--cancel current|all]`: send goal images to the planner.

Each image goes as a sensor_msgs/CompressedImage (JPEG/PNG bytes unchanged; frame_id =
file stem) on `litevloc/goal_image`; the planner visits them in order. `--wait S` waits
for the planner's status answering the last image and prints it.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from litevloc.cli.common import add_config_args, config_of
from litevloc.cli.main import UserError
from litevloc.runtime.planner.goal_client import GoalSendError, send_goals


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("goal", help="send goal images to the planner service")
    gs = p.add_subparsers(dest="goal_command", metavar="GOALCOMMAND")
    gs.required = True
    s = gs.add_parser("send", help="send goal images (JPEG/PNG) in order")
    s.add_argument("images", type=Path, nargs="*", help="goal images")
    s.add_argument("--cancel", choices=("current", "all"), default=None, help="cancel goals first")
    s.add_argument("--connect", action="append", default=[], metavar="ENDPOINT",
                   help="the planner's (or runtime's) endpoint, e.g. tcp/127.0.0.1:7448")
    s.add_argument("--namespace", default=None)
    s.add_argument("--wait", type=float, default=30.0, metavar="S",
                   help="wait up to S s for the planner's answer (0: do not wait); it places the goal "
                        "image first (seconds on a busy computer)")
    add_config_args(s)
    s.set_defaults(func=run_send)


def run_send(args: argparse.Namespace) -> int:
    import dataclasses

    from litevloc.runtime.transport.bus import Bus

    if not args.images and not args.cancel:
        raise UserError("give goal images and/or --cancel")
    images = []
    for p in args.images:
        if not p.is_file():
            raise UserError(f"goal image not found: {p}")
        images.append((p.stem, p.read_bytes()))
    cfg = config_of(args)
    z = dataclasses.replace(cfg.zenoh, listen=(), connect=tuple(args.connect) or cfg.zenoh.connect or
                            cfg.zenoh.listen, namespace=cfg.zenoh.namespace if args.namespace is None
                            else args.namespace)
    with Bus(z, node_name=f"{z.node_name}_goal") as bus:
        try:
            st = send_goals(bus, images, args.cancel, args.wait)
        except GoalSendError as exc:
            raise UserError(str(exc)) from exc
    print(f"sent {len(images)} goal image(s)" + (f", cancel {args.cancel}" if args.cancel else ""))
    if st is not None:
        print(f"planner: {st['state']}: {st['reason']}")
        return 0 if st["state"] != "failed" else 1
    if images and args.wait > 0:
        print("planner: no answer (is `litevloc plan` running and reachable?)")
        return 1
    return 0
