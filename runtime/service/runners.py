"""How a `Service` is driven: its stage threads supervised (realtime, deterministic), or every
message handled in the calling thread (sequential, the research-code baseline).

Both end with the same `ServiceResult`: why the run ended (`StopCause`) and the final status.
"""

from __future__ import annotations

import contextlib
import logging
import signal
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from enum import Enum
from typing import TYPE_CHECKING, Any

from litevloc.runtime.service.pacing import paced
from litevloc.runtime.service.queues import QueueBase
from litevloc.runtime.service.stages import StageState, _StageThread, traceback_summary

if TYPE_CHECKING:
    from litevloc.runtime.service.shell import Service

log = logging.getLogger(__name__)


class StopCause(str, Enum):
    """Why a run ended; `ServiceResult.ok` is False for a timeout or a failure."""

    END_OF_SOURCE = "end of source"
    REQUESTED = "stop requested"  # `stop()`, a signal
    TIMEOUT = "timeout"
    FAILED = "failed"


@dataclass
class ServiceResult:
    ok: bool
    reason: str  # "end of source", "SIGINT", "stage 'vloc' failed: ..."
    status: dict[str, Any] = field(default_factory=dict)
    cause: StopCause = StopCause.REQUESTED


@contextlib.contextmanager
def handle_signals(stop: Callable[[str], None], install: bool) -> Iterator[None]:
    """SIGINT / SIGTERM call `stop(name)` while the block runs (main thread only), then the old handlers return."""
    if not install or threading.current_thread() is not threading.main_thread():
        yield
        return
    old = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}

    def handler(signum: int, _frame: Any) -> None:
        stop(signal.Signals(signum).name)

    for s in old:
        signal.signal(s, handler)
    try:
        yield
    finally:
        for s, h in old.items():
            signal.signal(s, h)


def close_source(source: Any) -> None:
    """Close the source where it can be closed (a generator, a recording read in a child
    process), so what it holds (files, the reader process) ends with the service."""
    close = getattr(source, "close", None)
    if callable(close):
        try:
            close()
        except Exception as exc:  # e.g. a generator still running in a stuck source thread
            log.warning("could not close the source: %s", exc)


def run_threaded(svc: Service, timeout_s: float | None) -> ServiceResult:
    """Start the stages (downstream first) and watch them: a failed stage stops the run, the end
    of the source propagates downstream queue by queue, `timeout_s` stops it; then shut down."""
    svc.start_odometry_receiver()
    svc.status_stage.start()
    for st in reversed(svc.stages):
        st.start()
    deadline = None if timeout_s is None else time.monotonic() + timeout_s
    chain: list[tuple[_StageThread, list[QueueBase[Any]]]] = [
        (svc.source_stage, [svc.frames, svc.odometry]), (svc.vloc_stage, [svc.results]),
        (svc.fusion_stage, [svc.outbox])]
    closed: set[str] = set()
    while True:
        failed = [st for st in svc.stages if st.state == StageState.FAILED]
        if failed:
            svc.fail(f"stage {failed[0].name!r} failed: {failed[0].last_error}")
            break
        if svc.stop_event.is_set():
            break
        for st, downstream in chain:  # end of stream propagates downstream
            if st.finished.is_set() and st.state == StageState.DONE and st.name not in closed:
                closed.add(st.name)
                for q in downstream:  # (live Zenoh odometry, if any, ends with the recording too)
                    q.close()
        if svc.publish_stage.state == StageState.DONE:
            svc.end("end of source", StopCause.END_OF_SOURCE)
            break
        if deadline is not None and time.monotonic() > deadline:
            svc.stop(f"timeout after {timeout_s:g} s", StopCause.TIMEOUT)
            break
        svc.publish_stage.finished.wait(0.02)
    return _shutdown(svc)


def _shutdown(svc: Service) -> ServiceResult:
    """Stop the inputs, close the queues, join the stages (a stuck one is named in the reason)."""
    p = svc.params
    svc.stop_event.set()
    if svc.odometry_receiver is not None:
        with contextlib.suppress(Exception):
            svc.odometry_receiver.close()
    for q in svc.queues:
        q.close()
    for st in (svc.vloc_stage, svc.fusion_stage, svc.publish_stage):
        st.wake()
    stuck = [st.name for st in svc.stages if not st.join(p.stage_join_timeout_s)]
    # a stop ends the fusion promptly: odometry that arrived in its last moments is counted, not fused
    svc.shell_counters["odometry_left_at_stop"] = len(svc.odometry)
    if "source" not in stuck:
        close_source(svc.source)
    svc.status_stage.stop_event.set()
    svc.status_stage.join(p.stage_join_timeout_s)
    if svc.status_stage.state == StageState.CREATED:
        svc.status_tick()
    extra = f"; stage(s) {stuck} did not stop within {p.stage_join_timeout_s:g} s" if stuck else ""
    return svc.result(extra, ok=not stuck)


def run_sequential(svc: Service, timeout_s: float | None) -> ServiceResult:
    """Each message of the (paced) source to completion in this thread, the status every
    `status_period_s`; an exception ends the run as failed."""
    deadline = None if timeout_s is None else time.monotonic() + timeout_s
    next_status = time.monotonic()
    source = svc.source_stage
    source.state = StageState.RUNNING
    try:
        for msg in paced(svc.source, svc.rate, sleep=svc.stop_event.wait):
            if svc.stop_event.is_set():
                break
            svc.step(msg)
            if time.monotonic() >= next_status:
                svc.status_tick()
                next_status += svc.params.status_period_s
            if deadline is not None and time.monotonic() > deadline:
                svc.stop(f"timeout after {timeout_s:g} s", StopCause.TIMEOUT)
                break
        else:
            svc.end("end of source", StopCause.END_OF_SOURCE)
        source.state = StageState.DONE
        close_source(svc.source)
    except Exception as exc:
        source.state = StageState.FAILED
        source.last_error = traceback_summary(exc)
        svc.fail(f"sequential run failed: {source.last_error}", replace_reason=True)
    svc.status_tick()
    return svc.result()
