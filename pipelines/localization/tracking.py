"""The tracking state machine's states and transitions, and the state the service publishes.

The localizer (`vloc.VisualLocalizer.process`) moves INIT -> GLOBAL (GL over the whole map)
-> TRACKING (LL around the prior) -> LOST (`local_search.failures_before_lost` LL failures in a row)
-> GLOBAL on its next query. The service adds what only it knows, fusion, through
`published_state`: the state on `litevloc/status` and the LOST flag of the published poses.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum


class TrackingState(str, Enum):
    """A state of the localizer; the service publishes INIT, TRACKING or LOST (`published_state`)."""

    # printed and formatted as its value, like 3.11's StrEnum (Python 3.10 has none)
    def __str__(self) -> str:
        return str(self.value)

    def __format__(self, spec: str) -> str:
        return format(str(self.value), spec)

    INIT = "INIT"
    GLOBAL = "GLOBAL"
    TRACKING = "TRACKING"
    LOST = "LOST"


@dataclass(frozen=True)
class Transition:
    """One change of the localizer's state at query stamp `t_ns` (nanoseconds), with its reason."""

    t_ns: int
    from_state: TrackingState
    to_state: TrackingState
    reason: str


def published_state(
    localizer: TrackingState | None, fusion_initialised: bool, since_fix_s: float | None, lost_after_s: float,
) -> tuple[TrackingState, list[str]]:
    """The service's state and its reasons: INIT until fusion is initialised; then LOST when the
    localizer reported LOST with its latest result (`localizer`, None = not reported) or when the
    last VLoc fix fusion accepted is more than `lost_after_s` old (`since_fix_s`, seconds of
    sensor time, None = no fix yet), else TRACKING."""
    if not fusion_initialised:
        return TrackingState.INIT, ["waiting for the first accepted VLoc fix"]
    state, reasons = TrackingState.TRACKING, []
    if localizer == TrackingState.LOST:
        state = TrackingState.LOST
        reasons.append("localizer state machine is LOST")
    if since_fix_s is not None and since_fix_s > lost_after_s:
        state = TrackingState.LOST
        reasons.append(f"no VLoc fix accepted for {since_fix_s:.1f} s (> {lost_after_s:g})")
    return state, reasons
