"""The onboard service shell: stage threads and queues around the `LocalizationCore`.

```
source thread --frames: LatestMailbox (realtime) / BoundedFifo (deterministic)--> vloc stage
   (paced)    --odometry: BoundedFifo (never drops)----------------------------+
Zenoh odometry receiver (odometry_input: zenoh) ---> same odometry FIFO -------+--> fusion stage
vloc stage --results: BoundedFifo--> fusion stage (odometry first, then results)
fusion stage --outbox: BoundedFifo--> publisher stage (Zenoh)
status: every status_period_s (Periodic) -> publisher.publish_status + `Service.status()`
```

Every decision (fusion calls, tracking state, map->odom throttle, what to publish) is the
core's (`runtime.service.core`); this module only moves messages: it paces the
source, runs the VLoc callable and the core's steps in their threads (or inline), publishes
the core's typed outputs and assembles the status from the core's report, the queues and
the stages.

Injected callables (the lead plugs the real ones; tests use fakes):

* `vloc(frame: RgbdFrame, prior: VlocPrior | None) -> VlocOutcome` (e.g. `LocalizationResult`
  via `localizer_callable`, which also reports the localizer's tracking state); runs in the
  vloc thread.
* `on_odometry(odom) -> FusedPoseLike | None` and `on_vloc(result) -> FusionUpdateLike | None`
  (e.g. `fusion_callables(OnlineFusion)`); both run in the fusion thread only, so the fusion
  object needs no lock.
* `publisher`: `runtime.transport.bus.LiteVLocPublisher` or a fake with the same four methods.
* `after_odometry()` (optional): called in the fusion thread after each odometry message's
  outputs were handed on (published, with `publish_inline`), e.g. `OnlineFusion.flush`: the
  smoother update that `fusion_callables(..., defer_updates=True)` left for after the pose.

Fused covariances are converted with `covariance_to_ros` (e.g.
`base.geometry.gtsam_to_ros_covariance`) before publishing; default: already in ROS order.

Modes (`RuntimeConfig.mode`):
* `realtime`: the source is paced at `rate` (1 = recorded timing); frames go through a
  latest-value mailbox, so VLoc always takes the newest frame and stale ones are dropped
  (counted).
* `deterministic`: the same threads and queues in lockstep: before a frame is queued the
  fusion stage has consumed every earlier odometry message, and the source waits until
  that frame's result went through fusion. Every frame is processed, in order, and the
  published output is reproducible (tests, replay checks). Pacing is ignored.
* `sequential`: no threads; each message handled to completion in the calling thread
  in source order (the research-code baseline for benchmarks).

Shutdown: at the end of the source, queues are closed and each stage drains its input
and ends; `stop()` (SIGINT/SIGTERM with `install_signals=True`) ends everything promptly.
A stage that FAILS stops the service with its traceback summary in the result.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import signal
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
from numpy.typing import NDArray

from litevloc.base.errors import LiteVLocError
from litevloc.base.params.drift import T_BASE_CAMERA_OPTICAL
from litevloc.config.schema import RuntimeConfig
from litevloc.hw.messages import EncodedRgbdFrame, GroundTruthPose, Odometry, RgbdFrame, SourceMessage, StreamError
from litevloc.pipelines.localization.prior import Prior
from litevloc.runtime.metrics import LatencyWindow, jsonable, now_ns
from litevloc.runtime.service.core import (
    CoreOutput,
    FusedPoseLike,
    FusionUpdateLike,
    LocalizationCore,
    MapToOdomOut,
    OdometryFn,
    PoseOut,
    VlocOut,
    VlocOutcome,
    VlocUpdateFn,
)
from litevloc.runtime.service.frame_guard import RejectedFrame
from litevloc.runtime.service.pacing import paced
from litevloc.runtime.service.queues import BoundedFifo, LatestMailbox, QueueBase, QueueClosed
from litevloc.runtime.service.stages import Periodic, Stage, StageInput, StageState, _StageThread, configure_threads
from litevloc.runtime.service.vloc_prior import VlocPrior

if TYPE_CHECKING:
    from litevloc.pipelines.fusion.online import OnlineFusion
    from litevloc.pipelines.localization.vloc import VisualLocalizer

log = logging.getLogger(__name__)

VlocFn = Callable[[RgbdFrame, VlocPrior | None], VlocOutcome]

#: counters the shell owns (the core's are in `localization_core.CORE_COUNTERS`)
SHELL_COUNTERS = ("frames_in", "odometry_in", "odometry_ignored", "ground_truth_in", "vloc_calls", "poses_published",
                  "poses_withheld", "map_to_odom_published", "vloc_published", "status_published",
                  "frames_decoded", "frames_undecodable", "odometry_left_at_stop", "prior_waits_timed_out")


class PublisherLike(Protocol):
    def publish_pose(self, t_ns: int, T_map_base: NDArray[np.floating], covariance: NDArray[np.floating] | None,
                     lost: bool = False) -> bool: ...

    def publish_map_to_odom(self, t_ns: int, T_map_odom: NDArray[np.floating], lost: bool = False) -> bool: ...

    def publish_vloc(self, t_ns: int, T_map_camera: NDArray[np.floating],
                     covariance: NDArray[np.floating] | None) -> None: ...

    def publish_status(self, status: dict[str, Any]) -> None: ...


class ProviderReportLike(Protocol):
    """`models.ort.ProviderReport`: what the models' sessions run on."""

    def as_dict(self) -> dict[str, Any]: ...


class ServiceError(LiteVLocError, RuntimeError):
    """The service could not run (or stopped) because of a fatal error; the message says which."""


@dataclass
class ServiceResult:
    ok: bool
    reason: str  # "end of source", "SIGINT", "stage 'vloc' failed: ..."
    status: dict[str, Any] = field(default_factory=dict)


class _SourceThread(_StageThread):
    def __init__(self, name: str, stop: threading.Event, body: Callable[[], None]) -> None:
        super().__init__(name, stop, on_error="fail")
        self._body = body

    def _loop(self) -> None:
        self._body()
        if not self.stop_event.is_set():
            self._set_done()


class Service:
    """Runs source -> VLoc / odometry -> fusion -> publisher as described in the module docstring."""

    def __init__(
        self,
        source: Iterable[SourceMessage],
        vloc: VlocFn,
        on_odometry: OdometryFn,
        on_vloc: VlocUpdateFn,
        publisher: PublisherLike | None = None,
        params: RuntimeConfig | None = None,
        *,
        rate: float = 1.0,
        T_base_camera: NDArray[np.float64] = T_BASE_CAMERA_OPTICAL,
        covariance_to_ros: Callable[[NDArray[np.float64]], NDArray[np.float64]] | None = None,
        odometry_receiver: Callable[[Callable[[Odometry], None]], Any] | None = None,
        on_ground_truth: Callable[[GroundTruthPose], None] | None = None,
        on_fused: Callable[[FusedPoseLike], None] | None = None,
        after_odometry: Callable[[], None] | None = None,
        configure_thread_counts: bool = True,
    ) -> None:
        self.params = p = params or RuntimeConfig()
        if rate < 0:
            raise ValueError(f"rate must be >= 0, got {rate}")
        if p.odometry_input == "zenoh" and odometry_receiver is None:
            raise ValueError("runtime.odometry_input is 'zenoh' but no odometry receiver was given")
        self.source, self.rate = source, rate
        self.vloc_fn = vloc
        self.publisher = publisher
        self.on_ground_truth = on_ground_truth
        self.after_odometry = after_odometry
        self.core = LocalizationCore(on_odometry, on_vloc, p, np.asarray(T_base_camera, dtype=np.float64),
                                     covariance_to_ros, on_fused, window=p.latency_window)
        self._odometry_receiver_factory = odometry_receiver
        self.odometry_receiver: Any = None
        self.inputs: dict[str, Any] = {}  # other live inputs with a `report()` (e.g. the /initialpose subscriber)
        # the models' onnxruntime build and providers (`models.ort.provider_report`, or the VLoc process's):
        # the status's `models` entry, which `runtime.service.diagnostics` turns into `litevloc/models`
        self.models_report: Callable[[], ProviderReportLike] | None = None
        if configure_thread_counts:
            self.threads = configure_threads(p.cv_threads, p.ort_intra_op_threads, p.ort_inter_op_threads,
                                             p.gil_switch_interval_s)

        self._stop = threading.Event()
        self._stop_reason: str | None = None
        self._progress = threading.Condition()  # deterministic lockstep; realtime: results taken by fusion
        det = p.mode == "deterministic"
        w = p.latency_window
        self.frames: QueueBase[RgbdFrame | EncodedRgbdFrame] = (
            BoundedFifo("frames", capacity=1_000_000, window=w) if det else LatestMailbox("frames", window=w)
        )
        self.odometry: BoundedFifo[tuple[int, Odometry]] = BoundedFifo("odometry", p.odometry_queue_capacity,
                                                                         window=w)
        self.results: BoundedFifo[VlocOutcome] = BoundedFifo("vloc_results", p.result_queue_capacity, window=w)
        self.outbox: BoundedFifo[CoreOutput] = BoundedFifo("outbox", p.publish_queue_capacity, window=w)
        # publish_inline: the fusion thread publishes itself (one thread hop less); else via the outbox
        self._out: Callable[[CoreOutput], None] = self._handle_publish if p.publish_inline else self.outbox.put

        # state written by one thread each (see the stage that owns it)
        self.shell_counters: dict[str, int] = dict.fromkeys(SHELL_COUNTERS, 0)
        self._odom_pushed = 0
        self._odom_done = 0
        self._frames_pushed = 0
        self._vloc_done = 0
        self._results_put = 0  # vloc thread
        self._fix_in_flight = False  # vloc thread: the last result it put was an accepted fix
        self._prior_waiting = False  # vloc thread: waits in `_await_previous_fix`
        self._odom_at_result = 0  # fusion thread: odometry messages handled when it took the last result
        self._last_odom_wall: float | None = None
        self._last_frame_wall: float | None = None
        self.e2e = LatencyWindow(w)  # odometry into the FIFO -> pose handed to Zenoh (ms)
        self._t_start = time.monotonic()
        self._status: dict[str, Any] = {}
        self._fatal: str | None = None

        oe, mr = p.stage_on_error, p.stage_max_restarts
        self.source_stage = _SourceThread("source", self._stop, self._run_source)
        self.vloc_stage = Stage("vloc", [StageInput(self.frames, self._handle_frame)], self._stop, oe, mr,
                                nice=p.vloc_nice)
        self.fusion_stage = Stage(
            "fusion",
            [StageInput(self.odometry, self._handle_odometry_item), StageInput(self.results, self._handle_result)],
            self._stop, oe, mr, rt_priority=p.fusion_rt_priority,
        )
        self.publish_stage = Stage("publisher", [StageInput(self.outbox, self._handle_publish)], self._stop, oe, mr,
                                   rt_priority=p.fusion_rt_priority)
        self.status_stage = Periodic("status", self._status_tick, p.status_period_s, threading.Event())
        self.stages: list[_StageThread] = [self.source_stage, self.vloc_stage, self.fusion_stage, self.publish_stage]

    @property
    def counters(self) -> dict[str, int]:
        """A snapshot of the shell's and the core's counters."""
        return {**self.shell_counters, **self.core.counters}

    # ------------------------------------------------------------------ control
    def stop(self, reason: str = "stop requested") -> None:
        """Stop promptly (thread-safe, callable from a signal handler)."""
        if self._stop_reason is None:
            self._stop_reason = reason
        self._stop.set()
        for st in (self.vloc_stage, self.fusion_stage, self.publish_stage):
            st.wake()
        with contextlib.suppress(RuntimeError), self._progress:  # RuntimeError: re-entered from a signal
            self._progress.notify_all()

    @contextlib.contextmanager
    def _signals(self, install: bool) -> Iterator[None]:
        if not install or threading.current_thread() is not threading.main_thread():
            yield
            return
        old = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}

        def handler(signum: int, _frame: Any) -> None:
            self.stop(signal.Signals(signum).name)

        for s in old:
            signal.signal(s, handler)
        try:
            yield
        finally:
            for s, h in old.items():
                signal.signal(s, h)

    def run(self, install_signals: bool = False, timeout_s: float | None = None) -> ServiceResult:
        """Run until the source ends, `stop()`, a signal, a failed stage, or `timeout_s`."""
        with self._signals(install_signals):
            if self.params.mode == "sequential":
                return self._run_sequential(timeout_s)
            return self._run_threaded(timeout_s)

    def _run_threaded(self, timeout_s: float | None) -> ServiceResult:
        p = self.params
        if self._odometry_receiver_factory is not None and p.odometry_input == "zenoh":
            self.odometry_receiver = self._odometry_receiver_factory(self._push_odometry)
        self.status_stage.start()
        for st in reversed(self.stages):
            st.start()
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        chain: list[tuple[_StageThread, list[QueueBase[Any]]]] = [
            (self.source_stage, [self.frames, self.odometry]), (self.vloc_stage, [self.results]),
            (self.fusion_stage, [self.outbox])]
        closed: set[str] = set()
        while True:
            failed = [st for st in self.stages if st.state == StageState.FAILED]
            if failed:
                self._fatal = f"stage {failed[0].name!r} failed: {failed[0].last_error}"
                self.stop(self._fatal)
                break
            if self._stop.is_set():
                break
            for st, downstream in chain:  # end of stream propagates downstream
                if st.finished.is_set() and st.state == StageState.DONE and st.name not in closed:
                    closed.add(st.name)
                    for q in downstream:  # (live Zenoh odometry, if any, ends with the recording too)
                        q.close()
            if self.publish_stage.state == StageState.DONE:
                self._stop_reason = self._stop_reason or "end of source"
                break
            if deadline is not None and time.monotonic() > deadline:
                self.stop(f"timeout after {timeout_s:g} s")
                break
            self.publish_stage.finished.wait(0.02)
        return self._shutdown()

    def _shutdown(self) -> ServiceResult:
        p = self.params
        self._stop.set()
        if self.odometry_receiver is not None:
            with contextlib.suppress(Exception):
                self.odometry_receiver.close()
        for q in (self.frames, self.odometry, self.results, self.outbox):
            q.close()
        for st in (self.vloc_stage, self.fusion_stage, self.publish_stage):
            st.wake()
        stuck = [st.name for st in self.stages if not st.join(p.stage_join_timeout_s)]
        # a stop ends the fusion promptly: odometry that arrived in its last moments is counted, not fused
        self.shell_counters["odometry_left_at_stop"] = len(self.odometry)
        if "source" not in stuck:
            self._close_source()
        self.status_stage.stop_event.set()
        self.status_stage.join(p.stage_join_timeout_s)
        if self.status_stage.state == StageState.CREATED:
            self._status_tick()
        reason = self._stop_reason or "stopped"
        if stuck:
            reason += f"; stage(s) {stuck} did not stop within {p.stage_join_timeout_s:g} s"
        ok = self._fatal is None and not stuck and not reason.startswith("timeout")
        status = self.status()
        status["stop_reason"] = reason
        return ServiceResult(ok=ok, reason=reason, status=status)

    def _close_source(self) -> None:
        """Close the source where it can be closed (a generator, a recording read in a child
        process), so what it holds (files, the reader process) ends with the service."""
        close = getattr(self.source, "close", None)
        if callable(close):
            try:
                close()
            except Exception as exc:  # e.g. a generator still running in a stuck source thread
                log.warning("could not close the source: %s", exc)

    # ------------------------------------------------------------------ source thread
    def _push_odometry(self, odom: Odometry) -> None:
        self.odometry.put((now_ns(), odom))
        self._odom_pushed += 1

    def _wait_progress(self, pred: Callable[[], bool], what: str) -> bool:
        timeout = self.params.deterministic_timeout_s
        deadline = time.monotonic() + timeout
        ok = False
        while not ok and time.monotonic() < deadline:
            with self._progress:  # notified per item; the short slice also catches stage errors
                ok = self._progress.wait_for(lambda: pred() or self._stop.is_set(), 0.05)
        if not ok:
            raise ServiceError(f"deterministic mode: timed out after {timeout:g} s waiting for {what}")
        return not self._stop.is_set()

    def _errors(self) -> int:
        return self.vloc_stage.errors + self.fusion_stage.errors

    def _run_source(self) -> None:
        det = self.params.mode == "deterministic"
        live_odom = self.params.odometry_input == "zenoh"
        msgs: Iterable[SourceMessage] = self.source if det else paced(self.source, self.rate, sleep=self._stop.wait)
        for msg in msgs:
            if self._stop.is_set():
                return
            if isinstance(msg, Odometry):
                self.shell_counters["odometry_in"] += 1
                if live_odom:
                    self.shell_counters["odometry_ignored"] += 1
                else:
                    self._push_odometry(msg)
            elif isinstance(msg, RgbdFrame | EncodedRgbdFrame):
                self.shell_counters["frames_in"] += 1
                self._last_frame_wall = time.monotonic()
                if det:
                    pushed = self._odom_pushed

                    def odom_done(n: int = pushed) -> bool:
                        return self._odom_done >= n

                    if not self._wait_progress(odom_done, "odometry before a frame"):
                        return
                self.frames.put(msg)
                self._frames_pushed += 1
                if det:
                    k = self._frames_pushed

                    def frame_done(k: int = k) -> bool:  # an item skipped by a stage error counts as done
                        return self._vloc_done + self._errors() >= k

                    if not self._wait_progress(frame_done, f"VLoc + fusion of frame {msg.index} (t={msg.t_ns} ns)"):
                        return
            elif isinstance(msg, GroundTruthPose):
                self.shell_counters["ground_truth_in"] += 1
                if self.on_ground_truth is not None:
                    self.on_ground_truth(msg)

    def _notify_progress(self, waiter: bool = False) -> None:
        """Wake the source (deterministic mode) or a `waiter` (the VLoc thread, `_await_previous_fix`)."""
        if self.params.mode == "deterministic" or waiter:
            with self._progress:
                self._progress.notify_all()

    # ------------------------------------------------------------------ vloc thread
    def _handle_frame(self, frame: RgbdFrame | EncodedRgbdFrame) -> None:
        res = self._vloc(frame)
        try:
            self.results.put(res)
            self._results_put += 1
            self._fix_in_flight = bool(res.accepted)
        except QueueClosed:  # shutdown closed the queue while this frame was in VLoc: not a stage failure
            if not self._stop.is_set():
                raise

    def _vloc(self, frame: RgbdFrame | EncodedRgbdFrame) -> VlocOutcome:
        """VLoc of one frame; an `EncodedRgbdFrame` is decoded here, after the mailbox that drops
        stale frames, and one that does not decode is a counted, rejected result."""
        self.shell_counters["vloc_calls"] += 1
        if isinstance(frame, EncodedRgbdFrame):
            try:
                frame = frame.decode()
            except StreamError as exc:
                self.shell_counters["frames_undecodable"] += 1
                return RejectedFrame(frame.t_ns, False, f"bad frame: {exc}")
            self.shell_counters["frames_decoded"] += 1
        self._await_previous_fix()
        res = self.vloc_fn(frame, self.core.prior(frame.t_ns))
        self.core.note_fix(res)  # before the next frame's prior, whenever the fusion thread takes it
        return res

    def _await_previous_fix(self) -> None:
        """Realtime, after a frame whose result was an accepted fix: wait at most `prior_wait_ms`
        until fusion took that result and a fused pose followed it (the next odometry message),
        so the next frame's prior holds the fix. Without it the prior lagged one VLoc call (the
        result went into the queue as the next frame asked for its prior): a 4 s VLoc's prior
        was always two calls old, too old to confirm a pose. Timeouts are counted."""
        wait_ms = self.params.prior_wait_ms
        if self.params.mode != "realtime" or wait_ms <= 0 or not self._fix_in_flight:
            return
        n = self._results_put

        def fused_after() -> bool:  # `_vloc_done` counts every result taken, a failed one too
            return (self._vloc_done >= n and self._odom_done > self._odom_at_result) or self._stop.is_set()

        self._prior_waiting = True
        try:
            with self._progress:
                if not self._progress.wait_for(fused_after, wait_ms * 1e-3):
                    self.shell_counters["prior_waits_timed_out"] += 1
        finally:
            self._prior_waiting = False

    # ------------------------------------------------------------------ fusion thread
    def _handle_odometry_item(self, item: tuple[int, Odometry]) -> None:
        t_in, odom = item
        self._last_odom_wall = time.monotonic()
        try:
            for out in self.core.odometry(odom, t_in):
                self._out(out)
            if self.after_odometry is not None:  # work the pose must not wait for (deferred fusion update)
                self.after_odometry()
        finally:
            self._odom_done += 1
            self._notify_progress(waiter=self._prior_waiting)

    def _handle_result(self, res: VlocOutcome) -> None:
        try:
            for out in self.core.vloc_result(res):
                self._out(out)
        finally:
            self._odom_at_result = self._odom_done
            self._vloc_done += 1
            self._notify_progress(waiter=self._prior_waiting)

    # ------------------------------------------------------------------ publisher thread
    def _handle_publish(self, out: CoreOutput) -> None:
        pub, c = self.publisher, self.shell_counters
        if isinstance(out, PoseOut):
            if pub is None or pub.publish_pose(out.t_ns, out.T_map_base, out.covariance, out.lost):
                c["poses_published"] += 1
                self.e2e.add_since(out.t_in_ns)
            else:
                c["poses_withheld"] += 1
        elif isinstance(out, MapToOdomOut):
            if pub is None or pub.publish_map_to_odom(out.t_ns, out.T_map_odom, out.lost):
                c["map_to_odom_published"] += 1
        elif isinstance(out, VlocOut):
            if pub is not None:
                pub.publish_vloc(out.t_ns, out.T_map_camera, out.covariance)
            c["vloc_published"] += 1

    # ------------------------------------------------------------------ sequential baseline
    def _run_sequential(self, timeout_s: float | None) -> ServiceResult:
        p = self.params
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        next_status = time.monotonic()
        self.source_stage.state = StageState.RUNNING
        try:
            for msg in paced(self.source, self.rate, sleep=self._stop.wait):
                if self._stop.is_set():
                    break
                t_in = now_ns()
                if isinstance(msg, Odometry):
                    self.shell_counters["odometry_in"] += 1
                    self._handle_odometry_item((t_in, msg))
                elif isinstance(msg, RgbdFrame | EncodedRgbdFrame):
                    self.shell_counters["frames_in"] += 1
                    self._handle_result(self._vloc(msg))
                elif isinstance(msg, GroundTruthPose):
                    self.shell_counters["ground_truth_in"] += 1
                    if self.on_ground_truth is not None:
                        self.on_ground_truth(msg)
                while self.outbox.ready():  # publish inline
                    self._handle_publish(self.outbox.get_nowait())
                if time.monotonic() >= next_status:
                    self._status_tick()
                    next_status += p.status_period_s
                if deadline is not None and time.monotonic() > deadline:
                    self.stop(f"timeout after {timeout_s:g} s")
                    break
            else:
                self._stop_reason = self._stop_reason or "end of source"
            self.source_stage.state = StageState.DONE
            self._close_source()
        except Exception as exc:
            from litevloc.runtime.service.stages import traceback_summary

            self.source_stage.state = StageState.FAILED
            self.source_stage.last_error = traceback_summary(exc)
            self._fatal = f"sequential run failed: {self.source_stage.last_error}"
            self._stop_reason = self._fatal
        self._status_tick()
        reason = self._stop_reason or "stopped"
        ok = self._fatal is None and not reason.startswith("timeout")
        status = self.status()
        status["stop_reason"] = reason
        return ServiceResult(ok=ok, reason=reason, status=status)

    # ------------------------------------------------------------------ status
    def _status_tick(self) -> None:
        st = self._build_status()
        self._status = st
        if self.publisher is not None:
            try:
                self.publisher.publish_status(st)
                self.shell_counters["status_published"] += 1
            except Exception as exc:
                log.warning("status publish failed: %s", exc)

    def status(self) -> dict[str, Any]:
        """A fresh status snapshot (JSON-able)."""
        return self._build_status()

    def _build_status(self) -> dict[str, Any]:
        p = self.params
        core = self.core.report()
        state, reasons = core["state"], core["reasons"]
        stages = {st.name: st.status() for st in self.stages}
        for name, s in stages.items():
            if s["state"] == "FAILED":
                reasons.append(f"stage {name} FAILED: {s['last_error']}")
            elif s["errors"]:
                reasons.append(f"stage {name}: {s['errors']} error(s), last: {s['last_error']}")
        queues = {q.name: q.metrics().as_dict() for q in (self.frames, self.odometry, self.results, self.outbox)}
        for q in queues.values():
            if q["error"]:
                reasons.append(q["error"])
        odo: dict[str, Any] = {"input": p.odometry_input}
        if self.odometry_receiver is not None:
            odo.update(self.odometry_receiver.report(p.odometry_stale_s))
            if odo.get("skipped_total"):
                reasons.append(f"odometry input skipped {odo['skipped_total']} message(s): {odo['skipped']}")
            if odo.get("gaps"):
                reasons.append(f"odometry time jumped forward {odo['gaps']} time(s) "
                               f"(max {odo['max_gap_seen_s']:.3f} s)")
        gaps = self.core.counters["odometry_gaps"]
        if gaps and p.odometry_input == "source":
            reasons.append(f"odometry time jumped forward {gaps} time(s) (> {p.odometry_checks.max_gap_s:g} s)")
        running = not self._stop.is_set() and self.source_stage.state == StageState.RUNNING
        age = None if self._last_odom_wall is None else time.monotonic() - self._last_odom_wall
        odo["seconds_since_last"] = odo.get("seconds_since_last", age)
        since = odo["seconds_since_last"]
        waited = since if since is not None else time.monotonic() - self._t_start
        if running and waited > p.odometry_stale_s:
            reasons.append("no odometry received yet" if since is None else f"odometry stale: none for {since:.2f} s")
        f_age = time.monotonic() - (self._last_frame_wall or self._t_start)
        if running and p.mode == "realtime" and f_age > p.frame_stale_s:
            reasons.append("no camera frame received yet" if self._last_frame_wall is None
                            else f"camera frames stale: none for {f_age:.2f} s")
        if self._fatal:
            state = "FAILED"
        out: dict[str, Any] = {
            "t_wall": time.time(),
            "uptime_s": time.monotonic() - self._t_start,
            "mode": p.mode,
            **core,
            "state": state,
            "reasons": reasons,
            "running": running,
            "counters": self.counters,
            "frames_dropped": queues["frames"]["drops"],
            "odometry": odo,
            "latency": {"odometry_to_publish": self.e2e.summary()},
            "queues": queues,
            "stages": stages,
        }
        pub_status = getattr(self.publisher, "status", None)
        if callable(pub_status):
            try:
                out["bus"] = pub_status()
                problem = out["bus"].get("connectivity", {}).get("problem")
                if problem:
                    reasons.append(problem)
            except Exception as exc:
                out["bus"] = {"error": str(exc)}
        if self.inputs:
            out["inputs"] = {name: inp.report() for name, inp in self.inputs.items()}
        if self.models_report is not None:
            out["models"] = self.models_report().as_dict()
        return dict(jsonable(out))


# ---------------------------------------------------------------------- adapters
def localizer_callable(localizer: VisualLocalizer) -> VlocFn:
    """`pipelines.localization.vloc.VisualLocalizer` -> the service's `vloc(frame, prior)`.

    Each result carries the localizer's tracking state after the query (read in the VLoc
    thread that runs the localizer), so the status and the LOST flag follow its state machine."""

    def vloc(frame: RgbdFrame, prior: VlocPrior | None) -> VlocOutcome:
        if prior is None:
            res = localizer.process(frame.t_ns, frame.color, frame.depth, frame.K, None)
        elif prior.region is not None:  # an initial pose: GL near it, the fused prior ignored
            res = localizer.process(frame.t_ns, frame.color, frame.depth, frame.K, None, region=prior.region)
        else:
            res = localizer.process(frame.t_ns, frame.color, frame.depth, frame.K, Prior(
                prior.T_map_camera, prior.age_s, cov=prior.cov_position, travel_m=prior.travel_m))
        return dataclasses.replace(res, tracking_state=localizer.tracker.state)

    return vloc


def fusion_callables(fusion: OnlineFusion, defer_updates: bool = False) -> tuple[OdometryFn, VlocUpdateFn]:
    """An object with `add_odometry(t_ns, T_odom_base, covariance)` and
    `add_vloc(t_ns, T_map_camera, covariance, vote_only=False)` (the GTSAM `OnlineFusion`) -> the
    service's `(on_odometry, on_vloc)`; a rejected result with a provisional pose goes in as a vote.
    The VLoc covariance is passed as `pipelines.pnp` gives it:
    6x6, camera-frame right perturbation, order (tx, ty, tz, rx, ry, rz).

    `defer_updates`: odometry that makes a fusion keyframe due returns its pose before the
    smoother update, which waits for `fusion.flush()` (pass it to the `Service` as
    `after_odometry`, so the pose is published first)."""

    def on_odometry(o: Odometry) -> FusedPoseLike | None:
        if defer_updates:
            return fusion.add_odometry(o.t_ns, o.T_odom_base, o.covariance, defer_update=True)
        return fusion.add_odometry(o.t_ns, o.T_odom_base, o.covariance)

    def on_vloc(r: VlocOutcome) -> FusionUpdateLike:
        prov = r.provisional
        if not r.accepted and prov is not None:  # a provisional GL pose: a vote
            return fusion.add_vloc(r.t_ns, prov.T_map_camera, prov.covariance, vote_only=True)
        if r.T_map_camera is None:
            raise ValueError(f"VLoc result at t={r.t_ns} ns is accepted but has no pose")
        return fusion.add_vloc(r.t_ns, r.T_map_camera, r.covariance)

    return on_odometry, on_vloc
