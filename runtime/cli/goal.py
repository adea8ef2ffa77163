"""`litevloc goal send IMG... [--cancel current|all]`: send goal images to the planner.

Each image goes as a sensor_msgs/CompressedImage (JPEG/PNG bytes unchanged; frame_id =
file stem) on `litevloc/goal_image`; the planner visits them in order. `--wait S` waits
for the planner's status answering the last image and prints it.
"""

from __future__ import annotations

import argparse
import json
import threading
import time
from pathlib import Path
from typing import Any

from litevloc.runtime.cli.common import add_config_args, config_of
from litevloc.runtime.cli.main import UserError


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
    s.add_argument("--wait", type=float, default=5.0, metavar="S",
                   help="wait up to S s for the planner's answer (0: do not wait)")
    add_config_args(s)
    s.set_defaults(func=run_send)


def send_goals(bus: Any, images: list[tuple[str, bytes]], cancel: str | None = None,
               wait_s: float = 0.0) -> dict[str, Any] | None:
    """Publish (optional cancel, then) goal images; return the planner status that
    acknowledges the last one (None if not waiting or none came)."""
    from litevloc.hw import ros_msgs
    from litevloc.runtime.planner_service import KEYS

    got: list[dict[str, Any]] = []
    ev = threading.Condition()

    def on_status(sample: Any) -> None:
        st = json.loads(ros_msgs.deserialize(sample.payload.to_bytes(), ros_msgs.STRING).data)
        with ev:
            got.append(st)
            ev.notify_all()

    sub = bus.session.declare_subscriber(bus.key(KEYS["status"]), on_status)
    gpub = bus.publisher(KEYS["goal_image"], ros_msgs.COMPRESSED_IMAGE, reliable=True)
    cpub = bus.publisher(KEYS["goal_cancel"], ros_msgs.STRING, reliable=True)
    try:
        # a put before the planner's subscription has reached us would be dropped silently
        if images and not gpub.wait_for_subscribers(max(wait_s, 2.0)):
            raise UserError(f"no planner subscribes to goal images on {gpub.key_expr!r}: is `litevloc plan` "
                            "running and reachable (--connect)?")
        if cancel and not cpub.wait_for_subscribers(max(wait_s, 2.0)):
            raise UserError(f"no planner subscribes to {cpub.key_expr!r}: is `litevloc plan` running?")
        time.sleep(0.3)  # and let our status subscription reach the planner as well
        if cancel:
            cpub.put(ros_msgs.typestore().types[ros_msgs.STRING](data=cancel))
        t_ns = time.time_ns()
        for name, data in images:
            fmt = "png" if data[:4] == b"\x89PNG" else "jpeg"
            gpub.put(ros_msgs.compressed_image_msg(t_ns, data, fmt, name))
        if wait_s <= 0 or not images:
            return None
        last = images[-1][0]

        def about_last(s: dict[str, Any]) -> bool:  # the planner's reasons quote a goal as goal 'NAME'
            return bool(s.get("goal") == last or repr(last) in s.get("reason", ""))

        with ev:
            ev.wait_for(lambda: any(about_last(s) for s in got), wait_s)
            return next((s for s in reversed(got) if about_last(s)), None)
    finally:
        sub.undeclare()
        gpub.undeclare()
        cpub.undeclare()


def run_send(args: argparse.Namespace) -> int:
    import dataclasses

    from litevloc.runtime.bus import Bus

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
    with Bus(z) as bus:
        st = send_goals(bus, images, args.cancel, args.wait)
    print(f"sent {len(images)} goal image(s)" + (f", cancel {args.cancel}" if args.cancel else ""))
    if st is not None:
        print(f"planner: {st['state']}: {st['reason']}")
        return 0 if st["state"] != "failed" else 1
    if images and args.wait > 0:
        print("planner: no answer (is `litevloc plan` running and reachable?)")
        return 1
    return 0
