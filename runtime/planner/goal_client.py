"""Sending goal images to the planner service over Zenoh (`litevloc goal send`).

Each image goes as a sensor_msgs/CompressedImage (JPEG/PNG bytes unchanged; frame_id = its
name) on `litevloc/goal_image`; the planner visits them in order and answers on
`litevloc/planner_status`.
"""

from __future__ import annotations

import json
import threading
import time
from typing import Any

from litevloc.base.errors import LiteVLocError


class GoalSendError(LiteVLocError, RuntimeError):
    """No planner is there to take the goal images; the message says where it looked."""


def send_goals(bus: Any, images: list[tuple[str, bytes]], cancel: str | None = None,
               wait_s: float = 0.0) -> dict[str, Any] | None:
    """Publish (optional cancel, then) goal images; return the planner status that
    acknowledges the last one (None if not waiting or none came)."""
    from litevloc.hw import ros_msgs
    from litevloc.runtime.planner.node import KEYS

    got: list[dict[str, Any]] = []
    ev = threading.Condition()

    def on_status(sample: Any) -> None:
        st = json.loads(ros_msgs.deserialize(sample.payload.to_bytes(), ros_msgs.STRING).data)
        with ev:
            got.append(st)
            ev.notify_all()

    sub = bus.subscribe_topic(KEYS["status"], ros_msgs.STRING, on_status)
    gpub = bus.publisher(KEYS["goal_image"], ros_msgs.COMPRESSED_IMAGE, reliable=True)
    cpub = bus.publisher(KEYS["goal_cancel"], ros_msgs.STRING, reliable=True)
    try:
        # a put before the planner's subscription has reached us would be dropped silently
        if images and not gpub.wait_for_subscribers(max(wait_s, 2.0)):
            raise GoalSendError(f"no planner subscribes to goal images on {gpub.key_expr!r}: is `litevloc plan` "
                            "running and reachable (--connect)?")
        if cancel and not cpub.wait_for_subscribers(max(wait_s, 2.0)):
            raise GoalSendError(f"no planner subscribes to {cpub.key_expr!r}: is `litevloc plan` running?")
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
