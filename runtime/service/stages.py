"""Stage threads: `(input queues -> handler -> outputs)` loops that report and fail loudly.

* `Stage` reads one or more queues in priority order (an item of input 0 is always
  taken before one of input 1), calls that input's handler, records the handler's
  latency per input (sliding window: median/p99), and blocks on one shared `Waker`
  when every input is empty (no polling, no per-message lock). It finishes (DONE) when
  every input is closed and drained, and stops (STOPPED) when the stop event is set.
* A handler exception is caught and recorded with a short traceback summary. With
  `on_error="fail"` the stage becomes FAILED and its thread ends; with `"restart"` the
  failing item is skipped and the loop goes on, until `max_restarts` errors make it
  FAILED. Either way `status()` shows it and `failed` (an Event) is set on FAILED, so a
  supervisor (the service) can react; nothing dies silently.
* `Periodic` runs a callable every `period_s` (status publishing) with the same
  reporting.
* `configure_threads` is the ONE place where OpenCV / BLAS / onnxruntime thread counts
  are set for the target (2 CPUs by default); `ort_session_options` gives the matching
  onnxruntime options.
"""

from __future__ import annotations

import logging
import os
import sys
import threading
import traceback
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from enum import Enum
from typing import Any, Literal

from litevloc.runtime.metrics import LatencyWindow, now_ns
from litevloc.runtime.service.queues import QueueBase, QueueClosed, QueueEmpty, Waker

log = logging.getLogger(__name__)

OnError = Literal["fail", "restart"]


class StageState(str, Enum):
    """A stage thread's life: created, running, then done, stopped or failed."""

    # printed and formatted as its value, like 3.11's StrEnum (Python 3.10 has none)
    def __str__(self) -> str:
        return str(self.value)

    def __format__(self, spec: str) -> str:
        return format(str(self.value), spec)

    CREATED = "CREATED"
    RUNNING = "RUNNING"
    DONE = "DONE"  # inputs closed and drained
    STOPPED = "STOPPED"  # stop event
    FAILED = "FAILED"


def traceback_summary(exc: BaseException, lines: int = 6) -> str:
    """Exception type, message and the innermost frames, as a few lines of text."""
    tb = traceback.extract_tb(exc.__traceback__)[-3:]
    frames = [f"{os.path.basename(f.filename)}:{f.lineno} in {f.name}" for f in tb]
    return "\n".join([f"{type(exc).__name__}: {exc}", *frames][:lines])


@dataclass
class StageInput:
    """One input of a stage: its queue and the handler called with each item."""

    queue: QueueBase[Any]
    handler: Callable[[Any], None]

    def __post_init__(self) -> None:
        self.latency = LatencyWindow()


def lower_thread_priority(nice: int) -> int | None:
    """Raise the calling thread's nice value to at least `nice` (Linux: per thread; threads it
    starts afterwards inherit it). Returns the nice value in force, None where the platform
    has no per-thread priority (then the thread runs at normal priority; logged)."""
    if nice <= 0:
        return None
    if not sys.platform.startswith("linux"):
        log.warning("per-thread priority is Linux-only; %s keeps its priority", threading.current_thread().name)
        return None
    tid = threading.get_native_id()
    try:
        current = os.getpriority(os.PRIO_PROCESS, tid)
        if current < nice:
            os.setpriority(os.PRIO_PROCESS, tid, nice)
        return os.getpriority(os.PRIO_PROCESS, tid)
    except OSError as exc:
        log.warning("could not lower the priority of thread %s: %s", threading.current_thread().name, exc)
        return None


def use_realtime_priority(priority: int) -> str:
    """Put the calling thread in SCHED_FIFO at `priority` (1-99; 0: leave it as it is) and
    return what is in force, as text for the status.

    A latency-critical thread of a robot's stack (here: fusion and publishing) preempts every
    normal thread the moment it wakes; at normal priority on a 2-core machine it waits for a
    core behind the VLoc and I/O threads (`bench/runtime.py`, office: fused-pose p99 6.1 -> 1.3 ms
    together with inline publishing, deferred fusion updates and the recording reader process).
    SCHED_RESET_ON_FORK: threads this one starts run at normal priority.
    Needs CAP_SYS_NICE or an rtprio limit >= `priority` (systemd `LimitRTPRIO=`, or
    `@robot - rtprio 20` in /etc/security/limits.conf); without, the thread keeps normal
    priority and the reason is returned and logged (never an error: the service still works).
    """
    if priority <= 0:
        return "normal"
    if not sys.platform.startswith("linux"):
        why = f"normal (SCHED_FIFO {priority} is Linux-only)"
        log.warning("thread %s: %s", threading.current_thread().name, why)
        return why
    try:
        os.sched_setscheduler(threading.get_native_id(), os.SCHED_FIFO | os.SCHED_RESET_ON_FORK,
                              os.sched_param(priority))
    except OSError as exc:
        why = (f"normal (SCHED_FIFO {priority} not permitted: {exc.strerror}; give the service CAP_SYS_NICE or "
               f"an rtprio limit >= {priority})")
        log.warning("thread %s: %s", threading.current_thread().name, why)
        return why
    return f"SCHED_FIFO {priority}"


def call_in_low_priority_thread(fn: Callable[[], Any], nice: int) -> Any:
    """Run `fn` in a short-lived thread at nice `nice` and return its result (re-raising its
    exception). Threads that `fn` creates (e.g. onnxruntime's intra-op pool, made when a
    session is created) inherit the lower priority."""
    box: dict[str, Any] = {}

    def body() -> None:
        lower_thread_priority(nice)
        try:
            box["result"] = fn()
        except BaseException as exc:  # re-raised in the caller
            box["error"] = exc

    t = threading.Thread(target=body, name="litevloc-loader", daemon=True)
    t.start()
    t.join()
    if "error" in box:
        raise box["error"]
    return box.get("result")


class _StageThread:
    def __init__(
        self, name: str, stop: threading.Event, on_error: OnError = "fail", max_restarts: int = 3,
        nice: int = 0,
        rt_priority: int = 0,
    ) -> None:
        if on_error not in ("fail", "restart"):
            raise ValueError(f"stage {name!r}: on_error must be 'fail' or 'restart', got {on_error!r}")
        self.name = name
        self.stop_event = stop
        self.on_error = on_error
        self.max_restarts = max_restarts
        self.state: StageState = StageState.CREATED
        self.errors = 0
        self.last_error: str | None = None
        self.processed = 0
        self.nice = nice  # > 0: this thread runs at lower scheduling priority (see lower_thread_priority)
        self.nice_in_force: int | None = None
        self.rt_priority = rt_priority  # > 0: SCHED_FIFO at this priority (see use_realtime_priority)
        self.scheduling = "normal"
        self.failed = threading.Event()
        self.finished = threading.Event()
        self._thread = threading.Thread(target=self._main, name=f"litevloc-{name}", daemon=True)

    def start(self) -> None:
        self.state = StageState.RUNNING
        self._thread.start()

    def join(self, timeout: float) -> bool:
        """Wait up to `timeout` s; True if the thread has ended."""
        if self._thread.ident is None:
            return True
        self._thread.join(timeout)
        return not self._thread.is_alive()

    @property
    def alive(self) -> bool:
        return self._thread.is_alive()

    def _error(self, exc: Exception) -> bool:
        """Record a handler error; True if the stage must end (FAILED)."""
        self.errors += 1
        self.last_error = traceback_summary(exc)
        if self.on_error == "restart" and self.errors <= self.max_restarts:
            log.warning("stage %s: error %d/%d, skipping the item and going on:\n%s",
                        self.name, self.errors, self.max_restarts, self.last_error)
            return False
        log.error("stage %s FAILED:\n%s", self.name, self.last_error)
        self.state = StageState.FAILED
        self.failed.set()
        return True

    def _main(self) -> None:
        try:
            self.nice_in_force = lower_thread_priority(self.nice)
            self.scheduling = use_realtime_priority(self.rt_priority)
            self._loop()
        except Exception as exc:  # a bug in the loop itself, not in a handler
            self._error(exc)
            self.state = StageState.FAILED
            self.failed.set()
        finally:
            if self.state == StageState.RUNNING:
                self.state = StageState.STOPPED
            self.finished.set()

    def _set_done(self) -> None:
        """The loop ended because its input ended (not stopped, not failed)."""
        if self.state == StageState.RUNNING:
            self.state = StageState.DONE

    def _loop(self) -> None:  # pragma: no cover - overridden
        raise NotImplementedError

    def status(self) -> dict[str, Any]:
        return {"name": self.name, "state": str(self.state), "processed": self.processed, "errors": self.errors,
                "last_error": self.last_error, "alive": self.alive, "nice": self.nice_in_force,
                "scheduling": self.scheduling}


class BodyThread(_StageThread):
    """A stage thread that runs `body()` once (the paced source); DONE when it returns unstopped."""

    def __init__(self, name: str, stop: threading.Event, body: Callable[[], None]) -> None:
        super().__init__(name, stop, on_error="fail")
        self._body = body

    def _loop(self) -> None:
        self._body()
        if not self.stop_event.is_set():
            self._set_done()


class Stage(_StageThread):
    """A thread that takes items from `inputs` (in priority order) and calls their handlers."""

    def __init__(
        self,
        name: str,
        inputs: Sequence[StageInput],
        stop: threading.Event,
        on_error: OnError = "fail",
        max_restarts: int = 3,
        wait_s: float = 0.1,
        nice: int = 0,
        rt_priority: int = 0,
    ) -> None:
        super().__init__(name, stop, on_error, max_restarts, nice, rt_priority)
        if not inputs:
            raise ValueError(f"stage {name!r} needs at least one input")
        self.inputs = list(inputs)
        self.wait_s = wait_s
        self.waker = Waker()
        for inp in self.inputs:
            inp.queue.attach(self.waker)

    @classmethod
    def map(
        cls, name: str, inq: QueueBase[Any], fn: Callable[[Any], Any], outputs: Sequence[Any],
        stop: threading.Event, **kw: Any,
    ) -> Stage:
        """Single-input stage: `r = fn(item)`; a non-None `r` is put on every output queue."""

        def handler(item: Any) -> None:
            r = fn(item)
            if r is not None:
                for out in outputs:
                    out.put(r)

        return cls(name, [StageInput(inq, handler)], stop, **kw)

    def wake(self) -> None:
        """Wake the loop now (after setting the stop event, so it ends without waiting)."""
        self.waker.wake()

    def _ready(self) -> bool:
        # a closed input wakes the loop only once every input is closed: one closed beside an open,
        # empty one would make every wait return at once (a busy loop after the source ends)
        qs = [inp.queue for inp in self.inputs]
        return self.stop_event.is_set() or any(len(q) for q in qs) or all(q.closed for q in qs)

    def _loop(self) -> None:
        n = len(self.inputs)
        while not self.stop_event.is_set():
            closed = 0
            for inp in self.inputs:
                try:
                    item = inp.queue.get_nowait()
                except QueueEmpty:
                    continue
                except QueueClosed:
                    closed += 1
                    continue
                t0 = now_ns()
                try:
                    inp.handler(item)
                except Exception as exc:
                    if self._error(exc):
                        return
                    break
                inp.latency.add_since(t0)
                self.processed += 1
                break  # back to the highest-priority input
            else:
                if closed == n:
                    self.state = StageState.DONE
                    return
                self.waker.wait(self.wait_s, self._ready)
        self.state = StageState.STOPPED

    def status(self) -> dict[str, Any]:
        s = super().status()
        s["latency"] = {inp.queue.name: inp.latency.summary() for inp in self.inputs}
        return s


class Periodic(_StageThread):
    """Calls `fn()` every `period_s` seconds until stopped (and once more at stop if `final`)."""

    def __init__(
        self, name: str, fn: Callable[[], None], period_s: float, stop: threading.Event,
        on_error: OnError = "restart", max_restarts: int = 1_000_000, final: bool = True,
    ) -> None:
        super().__init__(name, stop, on_error, max_restarts)
        if not period_s > 0:
            raise ValueError(f"stage {name!r}: period_s must be > 0, got {period_s}")
        self.fn, self.period_s, self.final = fn, period_s, final
        self.latency = LatencyWindow(256)

    def _call(self) -> bool:
        t0 = now_ns()
        try:
            self.fn()
        except Exception as exc:
            return self._error(exc)
        self.latency.add_since(t0)
        self.processed += 1
        return False

    def _loop(self) -> None:
        next_t = now_ns()
        while not self.stop_event.is_set():
            if self._call():
                return
            next_t += int(self.period_s * 1e9)
            self.stop_event.wait(max(0.0, (next_t - now_ns()) * 1e-9))
        if self.final:
            self._call()
        self.state = StageState.STOPPED

    def status(self) -> dict[str, Any]:
        s = super().status()
        s["latency"] = {"tick": self.latency.summary()}
        return s


# ------------------------------------------------------------------ thread budget
_THREADS: dict[str, int] = {"cv": 2, "ort_intra_op": 2, "ort_inter_op": 1}


def configure_threads(
    cv_threads: int = 2, ort_intra_op: int = 2, ort_inter_op: int = 1, switch_interval_s: float | None = None
) -> dict[str, int]:
    """Set the thread counts of the native libraries for the target CPU budget.

    `switch_interval_s` (if given) sets `sys.setswitchinterval`: the longest a
    GIL-holding thread (Python glue of a VLoc step) makes a waiting one (fusion,
    publisher) wait; Python's default is 5 ms.

    OpenCV: `cv2.setNumThreads` (process-wide, immediate). BLAS/OpenMP: the usual
    environment variables, set only if absent (they take effect in libraries loaded
    after this call). onnxruntime: remembered here for `ort_session_options()` (its
    thread pools are per session). Returns the counts in force.
    """
    for name, v in (("cv_threads", cv_threads), ("ort_intra_op", ort_intra_op), ("ort_inter_op", ort_inter_op)):
        if v < 1:
            raise ValueError(f"{name} must be >= 1, got {v}")
    import cv2

    cv2.setNumThreads(cv_threads)
    if switch_interval_s is not None:
        sys.setswitchinterval(switch_interval_s)
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, str(ort_intra_op))
    _THREADS.update(cv=cv_threads, ort_intra_op=ort_intra_op, ort_inter_op=ort_inter_op)
    return dict(_THREADS)


def ort_session_options() -> Any:
    """onnxruntime.SessionOptions with the thread counts of `configure_threads` (sequential
    execution: one inference at a time per session, intra-op threads for parallelism)."""
    import onnxruntime as ort

    so = ort.SessionOptions()
    so.intra_op_num_threads = _THREADS["ort_intra_op"]
    so.inter_op_num_threads = _THREADS["ort_inter_op"]
    so.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    so.add_session_config_entry("session.intra_op.allow_spinning", "0")  # see models.ort.make_session
    return so
