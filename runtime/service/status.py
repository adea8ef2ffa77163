"""The service's status report (`litevloc/status`, JSON): the core's report, then what the
shell sees (stages, queues, odometry input, staleness of the inputs, the bus, live inputs, models,
the map in use with its version and switches).

Read from the service's public surface only (`Service.liveness()`, its queues, stages, core,
publisher); called from the status thread, or inline in sequential mode.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from litevloc.runtime.metrics import jsonable
from litevloc.runtime.service.health import odometry_input_reasons, queue_reasons, stage_reasons

if TYPE_CHECKING:
    from litevloc.runtime.service.shell import Service


@dataclass(frozen=True)
class Liveness:
    """Wall-clock facts of a run (s): whether the source is running, time since the start, since
    the last odometry message and camera frame (None: none yet), and the fatal error if any."""

    running: bool
    uptime_s: float
    odometry_age_s: float | None
    frame_age_s: float | None
    fatal: str | None


def build_status(svc: Service) -> dict[str, Any]:
    """A fresh status of `svc` (JSON-able); `reasons` in a fixed order: tracking (core), stages,
    queues, odometry input, stale inputs, bus connectivity."""
    p, live = svc.params, svc.liveness()
    core = svc.core.report()
    state, reasons = core["state"], core["reasons"]
    stages = {st.name: st.status() for st in svc.stages}
    stage_reasons(stages, reasons)
    queues = {q.name: q.metrics().as_dict() for q in svc.queues}
    queue_reasons(queues, reasons)
    odo = _odometry_status(svc, live, reasons)
    since = odo["seconds_since_last"]
    waited = since if since is not None else live.uptime_s
    if live.running and waited > p.odometry_stale_s:
        reasons.append("no odometry received yet" if since is None else f"odometry stale: none for {since:.2f} s")
    f_age = live.uptime_s if live.frame_age_s is None else live.frame_age_s
    if live.running and p.mode == "realtime" and f_age > p.frame_stale_s:
        reasons.append("no camera frame received yet" if live.frame_age_s is None
                       else f"camera frames stale: none for {f_age:.2f} s")
    out: dict[str, Any] = {
        "t_wall": time.time(), "uptime_s": live.uptime_s, "mode": p.mode, **core,
        "state": "FAILED" if live.fatal else state, "reasons": reasons, "running": live.running,
        "counters": svc.counters, "frames_dropped": queues["frames"]["drops"], "odometry": odo,
        "latency": {"odometry_to_publish": svc.e2e.summary()}, "queues": queues, "stages": stages,
    }
    pub_status = getattr(svc.publisher, "status", None)
    if callable(pub_status):
        try:  # what the core withheld or flagged is reported with the bus's counts
            out["bus"] = {**pub_status(), "withheld": svc.core.counters["poses_withheld"],
                          "flagged": svc.core.poses_flagged}
            problem = out["bus"].get("connectivity", {}).get("problem")
            if problem:
                reasons.append(problem)
        except Exception as exc:
            out["bus"] = {"error": str(exc)}
    if svc.inputs:
        out["inputs"] = {name: inp.report() for name, inp in svc.inputs.items()}
    if svc.models_report is not None:
        out["models"] = svc.models_report().as_dict()
    if svc.map_report is not None:
        out["map"] = svc.map_report()
    return dict(jsonable(out))


def _odometry_status(svc: Service, live: Liveness, reasons: list[str]) -> dict[str, Any]:
    """The status's `odometry` entry (the input, the receiver's report, the age of the last message)."""
    p = svc.params
    odo: dict[str, Any] = {"input": p.odometry_input}
    if svc.odometry_receiver is not None:
        odo.update(svc.odometry_receiver.report(p.odometry_stale_s))
        odometry_input_reasons(odo, reasons)
    gaps = svc.core.counters["odometry_gaps"]
    if gaps and p.odometry_input == "source":
        reasons.append(f"odometry time jumped forward {gaps} time(s) (> {p.odometry_checks.max_gap_s:g} s)")
    odo["seconds_since_last"] = odo.get("seconds_since_last", live.odometry_age_s)
    return odo
