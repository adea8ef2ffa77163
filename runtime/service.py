"""The onboard service skeleton: stage threads wired from injected callables.

```
source thread --frames: LatestMailbox (realtime) / BoundedFifo (deterministic)--> vloc stage
   (paced)    --odometry: BoundedFifo (never drops)----------------------------+
Zenoh odometry receiver (odometry_input: zenoh) ---> same odometry FIFO -------+--> fusion stage
vloc stage --results: BoundedFifo--> fusion stage (odometry first, then results)
fusion stage --outbox: BoundedFifo--> publisher stage (Zenoh)
status: every status_period_s (Periodic) -> publisher.publish_status + `Service.status()`
```

Injected callables (the lead plugs the real ones; tests use fakes):

* `vloc(frame: RgbdFrame, prior: VlocPrior | None) -> LocalizationResult`
  (anything with `t_ns, accepted, reason, T_map_camera, covariance`); runs in the vloc thread.
* `on_odometry(odom: Odometry) -> FusedPose | None` (anything with `t_ns, T_map_base,
  T_map_odom, covariance, initialised`); `on_vloc(result) -> update` (anything with
  `accepted`, `reason`, or None); both run in the fusion thread only, so the fusion
  object needs no lock. Only VLoc-accepted results are passed to `on_vloc`.
* `publisher`: `runtime.bus.LiteVLocPublisher` or a fake with the same four methods.

The prior for VLoc is the fused pose at the frame's stamp (`runtime.vloc_prior`): the latest
`T_map_odom` applied to the odometry interpolated at `t_frame`, times `T_base_camera`, with
its age (seconds since the last VLoc fix fusion accepted); None until fusion is initialised.
Fused covariances are converted with `covariance_to_ros` (e.g.
`bus.gtsam_to_ros_covariance`) before publishing; default: already in ROS order.

Tracking state (status `state`, and the LOST flag on published poses): INIT until a
fused pose is initialised; then TRACKING while a VLoc update was accepted by fusion
within `lost_after_s` of sensor time (odometry stamps), LOST otherwise or when the
optional `state_fn()` (e.g. the localizer's state machine) says LOST.

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
import logging
import signal
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from litevloc.base.errors import LiteVLocError
from litevloc.config.schema import RuntimeConfig
from litevloc.hw.messages import GroundTruthPose, Message, Odometry, RgbdFrame
from litevloc.pipelines.odometry_drift import T_BASE_CAMERA_OPTICAL
from litevloc.runtime.diagnostics import VlocStageTimes
from litevloc.runtime.metrics import LatencyWindow, jsonable, now_ns
from litevloc.runtime.pacing import paced
from litevloc.runtime.queues import BoundedFifo, LatestMailbox, QueueBase, QueueClosed
from litevloc.runtime.stages import Periodic, Stage, StageInput, StageState, _StageThread, configure_threads
from litevloc.runtime.vloc_prior import OdometryHistory, VlocPrior, prior_at

log = logging.getLogger(__name__)

VlocFn = Callable[[RgbdFrame, VlocPrior | None], Any]
OdometryFn = Callable[[Odometry], Any]
VlocUpdateFn = Callable[[Any], Any]


class PublisherLike(Protocol):
    def publish_pose(self, t_ns: int, T_map_base: NDArray[np.floating], covariance: NDArray[np.floating] | None,
                     lost: bool = False) -> bool: ...

    def publish_map_to_odom(self, t_ns: int, T_map_odom: NDArray[np.floating], lost: bool = False) -> bool: ...

    def publish_vloc(self, t_ns: int, T_map_camera: NDArray[np.floating],
                     covariance: NDArray[np.floating] | None) -> None: ...

    def publish_status(self, status: dict[str, Any]) -> None: ...


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
        source: Iterable[Message],
        vloc: VlocFn,
        on_odometry: OdometryFn,
        on_vloc: VlocUpdateFn,
        publisher: PublisherLike | None = None,
        params: RuntimeConfig | None = None,
        *,
        rate: float = 1.0,
        T_base_camera: NDArray[np.float64] = T_BASE_CAMERA_OPTICAL,
        covariance_to_ros: Callable[[NDArray[np.float64]], NDArray[np.float64]] | None = None,
        state_fn: Callable[[], str] | None = None,
        odometry_receiver: Callable[[Callable[[Odometry], None]], Any] | None = None,
        on_ground_truth: Callable[[GroundTruthPose], None] | None = None,
        on_fused: Callable[[Any], None] | None = None,
        configure_thread_counts: bool = True,
    ) -> None:
        self.params = p = params or RuntimeConfig()
        if rate < 0:
            raise ValueError(f"rate must be >= 0, got {rate}")
        if p.odometry_input == "zenoh" and odometry_receiver is None:
            raise ValueError("runtime.odometry_input is 'zenoh' but no odometry receiver was given")
        self.source, self.rate = source, rate
        self.vloc_fn, self.on_odometry, self.on_vloc = vloc, on_odometry, on_vloc
        self.publisher = publisher
        self.T_base_camera = np.asarray(T_base_camera, dtype=np.float64)
        self.covariance_to_ros = covariance_to_ros
        self.state_fn = state_fn
        self.on_ground_truth, self.on_fused = on_ground_truth, on_fused
        self._odometry_receiver_factory = odometry_receiver
        self.odometry_receiver: Any = None
        if configure_thread_counts:
            self.threads = configure_threads(p.cv_threads, p.ort_intra_op_threads, p.ort_inter_op_threads,
                                             p.gil_switch_interval_s)

        self._stop = threading.Event()
        self._stop_reason: str | None = None
        self._progress = threading.Condition()  # deterministic lockstep only
        det = p.mode == "deterministic"
        w = p.latency_window
        self.frames: QueueBase[RgbdFrame] = (
            BoundedFifo("frames", capacity=1_000_000, window=w) if det else LatestMailbox("frames", window=w)
        )
        self.odometry: BoundedFifo[tuple[int, Odometry]] = BoundedFifo("odometry", p.odometry_queue_capacity,
                                                                         window=w)
        self.results: BoundedFifo[Any] = BoundedFifo("vloc_results", p.result_queue_capacity, window=w)
        self.outbox: BoundedFifo[tuple[Any, ...]] = BoundedFifo("outbox", p.publish_queue_capacity, window=w)
        # publish_inline: the fusion thread publishes itself (one thread hop less); else via the outbox
        self._out: Callable[[tuple[Any, ...]], None] = self._handle_publish if p.publish_inline else self.outbox.put

        # state written by one thread each (see the stage that owns it)
        self.counters: dict[str, int] = dict.fromkeys(
            ("frames_in", "odometry_in", "odometry_ignored", "ground_truth_in", "vloc_calls", "vloc_accepted",
             "vloc_rejected", "fusion_accepted", "fusion_rejected", "odometry_fused", "poses_published",
             "poses_withheld", "map_to_odom_published", "vloc_published", "status_published",
             "odometry_rejected", "odometry_gaps", "vloc_votes", "fusion_initialised_by_votes"), 0)
        self.last_fused: Any = None
        self.odometry_history = OdometryHistory()  # fused odometry poses, for the prior at a frame's stamp
        self.sensor_now_ns: int | None = None
        self.last_vloc_accept_ns: int | None = None
        self.last_vloc_reason: str | None = None
        self.last_fusion_reason: str | None = None
        self._last_m2o_ns: int | None = None
        self._m2o_due = False
        self._odom_pushed = 0
        self._odom_done = 0
        self._frames_pushed = 0
        self._vloc_done = 0
        self._last_odom_wall: float | None = None
        self._last_frame_wall: float | None = None
        self._max_gap_s = p.odometry_checks.max_gap_s
        self.e2e = LatencyWindow(w)  # odometry into the FIFO -> pose handed to Zenoh (ms)
        self.vloc_times = VlocStageTimes(w)  # per-query extract/vpr/match/pnp ms (litevloc/diagnostics)
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
            self._stop, oe, mr,
        )
        self.publish_stage = Stage("publisher", [StageInput(self.outbox, self._handle_publish)], self._stop, oe, mr)
        self.status_stage = Periodic("status", self._status_tick, p.status_period_s, threading.Event())
        self.stages: list[_StageThread] = [self.source_stage, self.vloc_stage, self.fusion_stage, self.publish_stage]

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
        chain = [(self.source_stage, [self.frames, self.odometry]), (self.vloc_stage, [self.results]),
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
        msgs: Iterable[Message] = self.source if det else paced(self.source, self.rate, sleep=self._stop.wait)
        for msg in msgs:
            if self._stop.is_set():
                return
            if isinstance(msg, Odometry):
                self.counters["odometry_in"] += 1
                if live_odom:
                    self.counters["odometry_ignored"] += 1
                else:
                    self._push_odometry(msg)
            elif isinstance(msg, RgbdFrame):
                self.counters["frames_in"] += 1
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
                self.counters["ground_truth_in"] += 1
                if self.on_ground_truth is not None:
                    self.on_ground_truth(msg)

    def _notify_progress(self) -> None:
        if self.params.mode == "deterministic":
            with self._progress:
                self._progress.notify_all()

    # ------------------------------------------------------------------ vloc thread
    def prior(self, t_frame_ns: int | None = None) -> VlocPrior | None:
        """The VLoc prior at `t_frame_ns` (see the module docstring); at the newest odometry
        when None. None before fusion is initialised."""
        f = self.last_fused
        if f is None or not getattr(f, "initialised", True):
            return None
        T_m2o = getattr(f, "T_map_odom", None)
        t = int(f.t_ns) if t_frame_ns is None else int(t_frame_ns)
        got = None if T_m2o is None else prior_at(t, T_m2o, self.odometry_history, self.T_base_camera,
                                                   self.last_vloc_accept_ns)
        if got is None:  # a fusion without T_map_odom: its latest pose
            return VlocPrior(np.asarray(f.T_map_base, dtype=np.float64) @ self.T_base_camera, 0.0, False)
        return got

    def _handle_frame(self, frame: RgbdFrame) -> None:
        res = self._vloc(frame)
        try:
            self.results.put(res)
        except QueueClosed:  # shutdown closed the queue while this frame was in VLoc: not a stage failure
            if not self._stop.is_set():
                raise

    def _vloc(self, frame: RgbdFrame) -> Any:
        self.counters["vloc_calls"] += 1
        return self.vloc_fn(frame, self.prior(frame.t_ns))

    # ------------------------------------------------------------------ fusion thread
    def _handle_odometry_item(self, item: tuple[int, Odometry]) -> None:
        t_in, odom = item
        self._last_odom_wall = time.monotonic()
        if self.sensor_now_ns is not None and (odom.t_ns - self.sensor_now_ns) * 1e-9 > self._max_gap_s:
            self.counters["odometry_gaps"] += 1  # (the Zenoh receiver counts its own; this is every input)
        self.sensor_now_ns = odom.t_ns
        try:
            fused = self.on_odometry(odom)
            self.counters["odometry_fused"] += 1
            if fused is None and self.last_fused is not None:  # fusion refused it (time not increasing, bad pose)
                self.counters["odometry_rejected"] += 1
            if fused is not None:
                self.odometry_history.add(odom.t_ns, odom.T_odom_base)
                self.last_fused = fused
                if self.on_fused is not None:
                    self.on_fused(fused)
                self._emit_fused(fused, t_in)
        finally:
            self._odom_done += 1
            self._notify_progress()

    def tracking_state(self) -> tuple[str, list[str]]:
        """(INIT | TRACKING | LOST, reasons) from fusion/VLoc progress (see module docstring)."""
        reasons: list[str] = []
        f = self.last_fused
        if f is None or not getattr(f, "initialised", True):
            return "INIT", ["waiting for the first accepted VLoc fix"]
        state = "TRACKING"
        if self.state_fn is not None:
            s = str(self.state_fn())
            if s == "LOST":
                state = "LOST"
                reasons.append("localizer state machine is LOST")
        now, last = self.sensor_now_ns, self.last_vloc_accept_ns
        if now is not None and last is not None and (now - last) * 1e-9 > self.params.lost_after_s:
            state = "LOST"
            reasons.append(f"no VLoc fix accepted for {(now - last) * 1e-9:.1f} s (> {self.params.lost_after_s:g})")
        return state, reasons

    def _emit_fused(self, fused: Any, t_in: int) -> None:
        state, _ = self.tracking_state()
        lost = state == "LOST"
        if not getattr(fused, "initialised", True):
            return
        cov = getattr(fused, "covariance", None)
        if cov is not None and self.covariance_to_ros is not None:
            cov = self.covariance_to_ros(np.asarray(cov))
        self._out(("pose", t_in, int(fused.t_ns), fused.T_map_base, cov, lost))
        T_m2o = getattr(fused, "T_map_odom", None)
        if T_m2o is not None:
            due = self._m2o_due or self._last_m2o_ns is None or (
                (fused.t_ns - self._last_m2o_ns) * 1e-9 >= self.params.map_to_odom_period_s)
            if due:
                self._m2o_due = False
                self._last_m2o_ns = int(fused.t_ns)
                self._out(("map_to_odom", int(fused.t_ns), T_m2o, lost))

    def _handle_result(self, res: Any) -> None:
        try:
            self._fuse_result(res)
        finally:
            self._vloc_done += 1
            self._notify_progress()

    def _fuse_result(self, res: Any) -> None:
        self.vloc_times.add(getattr(res, "timings_ms", None))
        self.last_vloc_reason = str(getattr(res, "reason", ""))
        if not getattr(res, "accepted", False) or getattr(res, "T_map_camera", None) is None:
            self.counters["vloc_rejected"] += 1
            if getattr(res, "provisional", None) is not None:
                self._fuse_vote(res)
            return
        self.counters["vloc_accepted"] += 1
        update = self.on_vloc(res)
        ok = True if update is None else bool(getattr(update, "accepted", True))
        self.last_fusion_reason = None if update is None else str(getattr(update, "reason", ""))
        if not ok:
            self.counters["fusion_rejected"] += 1
            return
        self.counters["fusion_accepted"] += 1
        t = int(res.t_ns)
        self.last_vloc_accept_ns = t if self.last_vloc_accept_ns is None else max(self.last_vloc_accept_ns, t)
        self._m2o_due = True
        self._out(("vloc", t, res.T_map_camera, getattr(res, "covariance", None)))

    def _fuse_vote(self, res: Any) -> None:
        """A provisional (single-keyframe) GL pose: an initialisation vote for fusion only."""
        self.counters["vloc_votes"] += 1
        update = self.on_vloc(res)
        if update is not None and bool(getattr(update, "accepted", False)):
            self.counters["fusion_initialised_by_votes"] += 1
            # the LOST timer starts here: without an accepted fix within lost_after_s -> LOST
            t = int(res.t_ns)
            self.last_vloc_accept_ns = t if self.last_vloc_accept_ns is None else max(self.last_vloc_accept_ns, t)
            self._m2o_due = True

    # ------------------------------------------------------------------ publisher thread
    def _handle_publish(self, item: tuple[Any, ...]) -> None:
        kind = item[0]
        pub = self.publisher
        if kind == "pose":
            _, t_in, t_ns, T, cov, lost = item
            if pub is None or pub.publish_pose(t_ns, T, cov, lost):
                self.counters["poses_published"] += 1
                self.e2e.add_since(t_in)
            else:
                self.counters["poses_withheld"] += 1
        elif kind == "map_to_odom":
            _, t_ns, T, lost = item
            if pub is None or pub.publish_map_to_odom(t_ns, T, lost):
                self.counters["map_to_odom_published"] += 1
        elif kind == "vloc":
            _, t_ns, T, cov = item
            if pub is not None:
                pub.publish_vloc(t_ns, T, cov)
            self.counters["vloc_published"] += 1

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
                    self.counters["odometry_in"] += 1
                    self._handle_odometry_item((t_in, msg))
                elif isinstance(msg, RgbdFrame):
                    self.counters["frames_in"] += 1
                    self._handle_result(self._vloc(msg))
                elif isinstance(msg, GroundTruthPose):
                    self.counters["ground_truth_in"] += 1
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
        except Exception as exc:
            from litevloc.runtime.stages import traceback_summary

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
                self.counters["status_published"] += 1
            except Exception as exc:
                log.warning("status publish failed: %s", exc)

    def status(self) -> dict[str, Any]:
        """A fresh status snapshot (JSON-able)."""
        return self._build_status()

    def _build_status(self) -> dict[str, Any]:
        p = self.params
        state, reasons = self.tracking_state()
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
        if self.counters["odometry_gaps"] and p.odometry_input == "source":
            reasons.append(f"odometry time jumped forward {self.counters['odometry_gaps']} time(s) "
                           f"(> {self._max_gap_s:g} s)")
        if self.counters["odometry_rejected"]:
            reasons.append(f"fusion rejected {self.counters['odometry_rejected']} odometry message(s) "
                           "(time not increasing or invalid pose)")
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
            "state": state,
            "reasons": reasons,
            "running": running,
            "counters": dict(self.counters),
            "frames_dropped": queues["frames"]["drops"],
            "last_vloc_reason": self.last_vloc_reason,
            "last_fusion_reason": self.last_fusion_reason,
            "sensor_time_ns": self.sensor_now_ns,
            "odometry": odo,
            "latency": {"odometry_to_publish": self.e2e.summary()},
            "vloc_stages": self.vloc_times.summary(),
            "queues": queues,
            "stages": stages,
        }
        if self.state_fn is not None:
            out["vloc_state"] = str(self.state_fn())
        pub_status = getattr(self.publisher, "status", None)
        if callable(pub_status):
            try:
                out["bus"] = pub_status()
                problem = out["bus"].get("connectivity", {}).get("problem")
                if problem:
                    reasons.append(problem)
            except Exception as exc:
                out["bus"] = {"error": str(exc)}
        return dict(jsonable(out))


# ---------------------------------------------------------------------- adapters
def localizer_callable(localizer: Any) -> VlocFn:
    """`pipelines.localization.vloc.VisualLocalizer` -> the service's `vloc(frame, prior)`.

    Pair it with `state_fn=lambda: str(localizer.state)` so the status (and the LOST flag)
    follow the localizer's state machine."""

    def vloc(frame: RgbdFrame, prior: VlocPrior | None) -> Any:
        if prior is None:
            return localizer.process(frame.t_ns, frame.color, frame.depth, frame.K, None)
        return localizer.process(frame.t_ns, frame.color, frame.depth, frame.K, prior.T_map_camera,
                                 prior_age_s=prior.age_s)

    return vloc


def fusion_callables(fusion: Any) -> tuple[OdometryFn, VlocUpdateFn]:
    """An object with `add_odometry(t_ns, T_odom_base, covariance)` and
    `add_vloc(t_ns, T_map_camera, covariance, vote_only=False)` (the GTSAM `OnlineFusion`) -> the
    service's `(on_odometry, on_vloc)`; a rejected result with a provisional pose goes in as a vote.
    The VLoc covariance is passed as `pipelines.pnp` gives it:
    6x6, camera-frame right perturbation, order (tx, ty, tz, rx, ry, rz)."""

    def on_odometry(o: Odometry) -> Any:
        return fusion.add_odometry(o.t_ns, o.T_odom_base, o.covariance)

    def on_vloc(r: Any) -> Any:
        prov = getattr(r, "provisional", None)
        if not getattr(r, "accepted", True) and prov is not None:  # a provisional GL pose: a vote
            return fusion.add_vloc(r.t_ns, prov.T_map_camera, prov.covariance, vote_only=True)
        return fusion.add_vloc(r.t_ns, r.T_map_camera, r.covariance)

    return on_odometry, on_vloc
