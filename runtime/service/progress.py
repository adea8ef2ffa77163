"""Hand-offs between the service's threads: the deterministic lockstep and the realtime wait
for the previous fix, on one condition variable.

Each counter is written by one thread (named beside it) and read by the others; a writer
notifies the condition when a reader may be waiting (deterministic mode, or the VLoc thread
in `await_previous_fix`).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

from litevloc.base.errors import LiteVLocError


class ServiceError(LiteVLocError, RuntimeError):
    """The service could not run (or stopped) because of a fatal error; the message says which."""


class Progress:
    """Counts of what went through each stage, and the waits on them.

    `deterministic`: the source waits for the fusion of every earlier message
    (`wait_odometry_done`, `wait_frame_done`) for at most `timeout_s` each; `stop` ends any wait."""

    def __init__(self, deterministic: bool, timeout_s: float, stop: threading.Event) -> None:
        self.deterministic, self.timeout_s, self._stop = deterministic, timeout_s, stop
        self.cond = threading.Condition()  # deterministic lockstep; realtime: results taken by fusion
        self.odom_pushed = 0  # source thread (or the Zenoh receiver)
        self.frames_pushed = 0  # source thread
        self.results_put = 0  # vloc thread
        self.fix_in_flight = False  # vloc thread: the last result it put was an accepted fix
        self.prior_waiting = False  # vloc thread: waits in `await_previous_fix`
        self.odom_done = 0  # fusion thread
        self.vloc_done = 0  # fusion thread: every result taken, a failed one too
        self.odom_at_result = 0  # fusion thread: odometry messages handled when it took the last result

    # ------------------------------------------------------------------ fusion thread
    def odometry_handled(self) -> None:
        self.odom_done += 1
        self.notify(waiter=self.prior_waiting)

    def result_handled(self) -> None:
        self.odom_at_result = self.odom_done
        self.vloc_done += 1
        self.notify(waiter=self.prior_waiting)

    def notify(self, waiter: bool = False) -> None:
        """Wake the source (deterministic mode) or a `waiter` (the VLoc thread, `await_previous_fix`)."""
        if self.deterministic or waiter:
            with self.cond:
                self.cond.notify_all()

    def wake_all(self) -> None:
        """Wake every waiter (a stop); may be re-entered from a signal handler."""
        try:
            with self.cond:
                self.cond.notify_all()
        except RuntimeError:  # re-entered from a signal while the condition is held
            pass

    # ------------------------------------------------------------------ vloc thread
    def await_previous_fix(self, wait_ms: float) -> bool:
        """After a frame whose result was an accepted fix: wait at most `wait_ms` until fusion took
        that result and a fused pose followed it (the next odometry message), so the next frame's
        prior holds the fix (else the prior lags one VLoc call). False when the wait timed out."""
        if wait_ms <= 0 or not self.fix_in_flight:
            return True
        n = self.results_put

        def fused_after() -> bool:
            return (self.vloc_done >= n and self.odom_done > self.odom_at_result) or self._stop.is_set()

        self.prior_waiting = True
        try:
            with self.cond:
                return bool(self.cond.wait_for(fused_after, wait_ms * 1e-3))
        finally:
            self.prior_waiting = False

    def result_put(self, accepted: bool) -> None:
        self.results_put += 1
        self.fix_in_flight = accepted

    # ------------------------------------------------------------------ source thread (deterministic)
    def wait(self, pred: Callable[[], bool], what: str) -> bool:
        """Wait until `pred()` (or a stop); False on a stop, `ServiceError` after `timeout_s`."""
        deadline = time.monotonic() + self.timeout_s
        ok = False
        while not ok and time.monotonic() < deadline:
            with self.cond:  # notified per item; the short slice also catches stage errors
                ok = self.cond.wait_for(lambda: pred() or self._stop.is_set(), 0.05)
        if not ok:
            raise ServiceError(f"deterministic mode: timed out after {self.timeout_s:g} s waiting for {what}")
        return not self._stop.is_set()
