"""The status's health reasons that the shell sees in its stages, queues and odometry input
(the tracking reasons are the core's, `LocalizationCore.report`).

Each function appends English sentences to `reasons` in the status's order; they are read by
people and by `runtime.service.diagnostics` as text, never branched on.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any


def stage_reasons(stages: Mapping[str, Mapping[str, Any]], reasons: list[str]) -> None:
    """A FAILED stage, or a stage that had errors (skipped items, restarts)."""
    for name, s in stages.items():
        if s["state"] == "FAILED":
            reasons.append(f"stage {name} FAILED: {s['last_error']}")
        elif s["errors"]:
            reasons.append(f"stage {name}: {s['errors']} error(s), last: {s['last_error']}")


def queue_reasons(queues: Mapping[str, Mapping[str, Any]], reasons: list[str]) -> None:
    for q in queues.values():
        if q["error"]:
            reasons.append(q["error"])


def odometry_input_reasons(odo: Mapping[str, Any], reasons: list[str]) -> None:
    """What the Zenoh odometry receiver's report (`hw.odometry.OdometryReceiver.report`) says."""
    if odo.get("skipped_total"):
        reasons.append(f"odometry input skipped {odo['skipped_total']} message(s): {odo['skipped']}")
    if odo.get("gaps"):
        reasons.append(f"odometry time jumped forward {odo['gaps']} time(s) (max {odo['max_gap_seen_s']:.3f} s)")

