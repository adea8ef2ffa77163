"""The onboard service shell: stage threads and queues around the `LocalizationCore`.

```
source thread --frames: LatestMailbox (realtime) / BoundedFifo (deterministic)--> vloc stage
   (paced)    --odometry: BoundedFifo (never drops)----------------------------+
Zenoh odometry receiver (odometry_input: zenoh) ---> same odometry FIFO -------+--> fusion stage
vloc stage --results: BoundedFifo--> fusion stage (odometry first, then results)
fusion stage --outbox: BoundedFifo--> publisher stage (Zenoh)
status: every status_period_s (Periodic) -> publisher.publish_status + `Service.status()`
```

Every decision (fusion calls, tracking state, map->odom throttle, what to publish and how) is
the core's (`runtime.service.core`); this module only moves messages: it paces the source,
runs the VLoc callable and the core's steps in their threads (or inline), hands the core's
typed outputs to the publisher as they are and assembles the status from the core's report,
the queues and the stages.

What it is given (the lead plugs the real ones; tests use fakes):

* `vloc(frame: RgbdFrame, prior: VlocPrior | None) -> VlocOutcome` (e.g. `LocalizationResult`
  via `localizer_callable`, which also reports the localizer's tracking state); runs in the
  vloc thread.
* `core`: a `LocalizationCore` with its `FusionPort` (e.g. `runtime.service.fusion_port`);
  its steps run in the fusion thread only, so the fusion object needs no lock.
* `ports` (`ServicePorts`): the publisher (`runtime.transport.bus.LiteVLocPublisher` or a fake
  with the same four methods), the Zenoh odometry receiver's factory, the ground-truth sink.

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

import dataclasses
import logging
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from functools import partial
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
from numpy.typing import NDArray

from litevloc.hw.messages import EncodedRgbdFrame, GroundTruthPose, Odometry, RgbdFrame, SourceMessage, StreamError
from litevloc.pipelines.localization.prior import Prior
from litevloc.runtime.metrics import LatencyWindow, now_ns
from litevloc.runtime.service.core import CoreOutput, LocalizationCore, MapToOdomOut, PoseOut, VlocOut, VlocOutcome
from litevloc.runtime.service.frame_guard import RejectedFrame
from litevloc.runtime.service.pacing import paced
from litevloc.runtime.service.progress import Progress
from litevloc.runtime.service.queues import BoundedFifo, LatestMailbox, QueueBase, QueueClosed
from litevloc.runtime.service.runners import ServiceResult, StopCause, handle_signals, run_sequential, run_threaded
from litevloc.runtime.service.stages import (
    BodyThread,
    Periodic,
    Stage,
    StageInput,
    StageState,
    _StageThread,
    configure_threads,
)
from litevloc.runtime.service.status import Liveness, build_status
from litevloc.runtime.service.vloc_prior import VlocPrior

if TYPE_CHECKING:
    from litevloc.pipelines.localization.vloc import VisualLocalizer

log = logging.getLogger(__name__)


def _reached(count: Callable[[], int], target: int) -> bool:
    """Whether the running `count()` has reached `target` (the deterministic mode's hand-offs)."""
    return count() >= target

VlocFn = Callable[[RgbdFrame, VlocPrior | None], VlocOutcome]

#: counters the shell owns (the core's are in `core.CORE_COUNTERS`)
SHELL_COUNTERS = ("frames_in", "odometry_in", "odometry_ignored", "ground_truth_in", "vloc_calls", "poses_published",
                  "map_to_odom_published", "vloc_published", "status_published",
                  "frames_decoded", "frames_undecodable", "odometry_left_at_stop", "prior_waits_timed_out")


class PublisherLike(Protocol):
    """Serialises what the core decided to publish (`runtime.transport.bus.LiteVLocPublisher`)."""

    def publish_pose(self, t_ns: int, T_map_base: NDArray[np.floating],
                     covariance: NDArray[np.floating] | None) -> None: ...

    def publish_map_to_odom(self, t_ns: int, T_map_odom: NDArray[np.floating]) -> None: ...

    def publish_vloc(self, t_ns: int, T_map_camera: NDArray[np.floating],
                     covariance: NDArray[np.floating] | None) -> None: ...

    def publish_status(self, status: dict[str, Any]) -> None: ...


class ProviderReportLike(Protocol):
    """`models.ort.ProviderReport`: what the models' sessions run on."""

    def as_dict(self) -> dict[str, Any]: ...


OdometryReceiverFactory = Callable[[Callable[[Odometry], None]], Any]


@dataclass(frozen=True)
class ServicePorts:
    """Where the service's messages go and where live odometry comes from.

    `publisher`: None publishes nothing (counted as published); `odometry_receiver`: called with the
    odometry sink when the run starts (`runtime.odometry_input: zenoh`), returns an object with
    `report(stale_s)` and `close()`; `on_ground_truth`: each ground-truth message of the source."""

    publisher: PublisherLike | None = None
    odometry_receiver: OdometryReceiverFactory | None = None
    on_ground_truth: Callable[[GroundTruthPose], None] | None = None


class Service:
    """Runs source -> VLoc / odometry -> fusion -> publisher as described in the module docstring.

    `rate`: the source's pace (1 = recorded timing, 0 = as fast as it comes; realtime and
    sequential modes); `configure_thread_counts`: set the process's OpenCV / BLAS / onnxruntime
    thread counts from the settings (`stages.configure_threads`). The settings are the core's."""

    def __init__(self, source: Iterable[SourceMessage], vloc: VlocFn, core: LocalizationCore,
                 ports: ServicePorts | None = None, *, rate: float = 1.0, configure_thread_counts: bool = True) -> None:
        ports = ports or ServicePorts()
        self.params = p = core.params
        if rate < 0:
            raise ValueError(f"rate must be >= 0, got {rate}")
        if p.odometry_input == "zenoh" and ports.odometry_receiver is None:
            raise ValueError("runtime.odometry_input is 'zenoh' but no odometry receiver was given")
        self.source, self.rate, self.vloc_fn, self.core = source, rate, vloc, core
        self.publisher, self.on_ground_truth = ports.publisher, ports.on_ground_truth
        self._odometry_receiver_factory = ports.odometry_receiver
        self.odometry_receiver: Any = None
        self.inputs: dict[str, Any] = {}  # other live inputs with a `report()` (e.g. the /initialpose subscriber)
        # the models' onnxruntime build and providers (`models.ort.provider_report`, or the VLoc process's):
        # the status's `models` entry, which `runtime.service.diagnostics` turns into `litevloc/models`
        self.models_report: Callable[[], ProviderReportLike] | None = None
        # the map in use and its switches (`runtime.service.map_switch.MapSwitcher.report`): the status's `map`
        self.map_report: Callable[[], dict[str, Any]] | None = None
        if configure_thread_counts:
            self.threads = configure_threads(p.cv_threads, p.ort_intra_op_threads, p.ort_inter_op_threads,
                                             p.gil_switch_interval_s)
        self._stop = threading.Event()
        self._stop_reason: str | None = None
        self._stop_cause = StopCause.REQUESTED
        self.progress = Progress(p.mode == "deterministic", p.deterministic_timeout_s, self._stop)
        w = p.latency_window
        self.frames: QueueBase[RgbdFrame | EncodedRgbdFrame] = (
            BoundedFifo("frames", capacity=1_000_000, window=w) if p.mode == "deterministic"
            else LatestMailbox("frames", window=w))
        self.odometry: BoundedFifo[tuple[int, Odometry]] = BoundedFifo("odometry", p.odometry_queue_capacity,
                                                                         window=w)
        self.results: BoundedFifo[VlocOutcome] = BoundedFifo("vloc_results", p.result_queue_capacity, window=w)
        self.outbox: BoundedFifo[CoreOutput] = BoundedFifo("outbox", p.publish_queue_capacity, window=w)
        # publish_inline: the fusion thread publishes itself (one thread hop less); else via the outbox
        self._out: Callable[[CoreOutput], None] = self._handle_publish if p.publish_inline else self.outbox.put
        self.shell_counters: dict[str, int] = dict.fromkeys(SHELL_COUNTERS, 0)  # each written by one thread
        self._last_odom_wall: float | None = None
        self._last_frame_wall: float | None = None
        self.e2e = LatencyWindow(w)  # odometry into the FIFO -> pose handed to Zenoh (ms)
        self._t_start = time.monotonic()
        self._status: dict[str, Any] = {}
        self._fatal: str | None = None
        oe, mr = p.stage_on_error, p.stage_max_restarts
        self.source_stage = BodyThread("source", self._stop, self._run_source)
        self.vloc_stage = Stage("vloc", [StageInput(self.frames, self._handle_frame)], self._stop, oe, mr,
                                nice=p.vloc_nice)
        self.fusion_stage = Stage(
            "fusion",
            [StageInput(self.odometry, self._handle_odometry_item), StageInput(self.results, self._handle_result)],
            self._stop, oe, mr, rt_priority=p.fusion_rt_priority,
        )
        self.publish_stage = Stage("publisher", [StageInput(self.outbox, self._handle_publish)], self._stop, oe, mr,
                                   rt_priority=p.fusion_rt_priority)
        self.status_stage = Periodic("status", self.status_tick, p.status_period_s, threading.Event())
        self.stages: list[_StageThread] = [self.source_stage, self.vloc_stage, self.fusion_stage, self.publish_stage]

    @property
    def counters(self) -> dict[str, int]:
        """A snapshot of the shell's and the core's counters."""
        return {**self.shell_counters, **self.core.counters}

    # ------------------------------------------------------------------ control
    def stop(self, reason: str = "stop requested", cause: StopCause = StopCause.REQUESTED) -> None:
        """Stop promptly (thread-safe, callable from a signal handler); the first reason given stays."""
        if self._stop_reason is None:
            self._stop_reason, self._stop_cause = reason, cause
        self._stop.set()
        for st in (self.vloc_stage, self.fusion_stage, self.publish_stage):
            st.wake()
        self.progress.wake_all()

    def end(self, reason: str, cause: StopCause) -> None:
        """Record why the run ended unless a reason was given first (the source ended, it failed)."""
        if self._stop_reason is None:
            self._stop_reason, self._stop_cause = reason, cause

    def fail(self, message: str, replace_reason: bool = False) -> None:
        """Stop because of a fatal error (a failed stage; the sequential run's exception, whose
        message replaces any earlier reason)."""
        self._fatal = message
        if replace_reason:
            self._stop_reason = None
        self.stop(message, StopCause.FAILED)

    @property
    def stop_event(self) -> threading.Event:
        return self._stop

    def run(self, install_signals: bool = False, timeout_s: float | None = None) -> ServiceResult:
        """Run until the source ends, `stop()`, a signal, a failed stage, or `timeout_s`."""
        with handle_signals(self.stop, install_signals):
            if self.params.mode == "sequential":
                return run_sequential(self, timeout_s)
            return run_threaded(self, timeout_s)

    def start_odometry_receiver(self) -> None:
        """Live odometry (`runtime.odometry_input: zenoh`): the receiver starts feeding the odometry FIFO."""
        if self._odometry_receiver_factory is not None and self.params.odometry_input == "zenoh":
            self.odometry_receiver = self._odometry_receiver_factory(self._push_odometry)

    def result(self, extra: str = "", ok: bool = True) -> ServiceResult:
        """The run's result: why it ended (+ `extra`), ok unless it timed out or failed (or not `ok`)."""
        reason = (self._stop_reason or "stopped") + extra
        cause = self._stop_cause
        ok = ok and self._fatal is None and cause not in (StopCause.TIMEOUT, StopCause.FAILED)
        status = self.status()
        status["stop_reason"] = reason
        return ServiceResult(ok=ok, reason=reason, status=status, cause=cause)

    # ------------------------------------------------------------------ source thread
    def _push_odometry(self, odom: Odometry) -> None:
        self.odometry.put((now_ns(), odom))
        self.progress.odom_pushed += 1

    def _run_source(self) -> None:
        det = self.params.mode == "deterministic"
        live_odom = self.params.odometry_input == "zenoh"
        pg = self.progress
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
                if det and not pg.wait(partial(_reached, lambda: pg.odom_done, pg.odom_pushed),
                                       "odometry before a frame"):
                    return
                self.frames.put(msg)
                pg.frames_pushed += 1
                # an item skipped by a stage error counts as done
                if det and not pg.wait(partial(_reached, lambda: pg.vloc_done + self._errors(), pg.frames_pushed),
                                       f"VLoc + fusion of frame {msg.index} (t={msg.t_ns} ns)"):
                    return
            elif isinstance(msg, GroundTruthPose):
                self._ground_truth(msg)

    def _ground_truth(self, msg: GroundTruthPose) -> None:
        self.shell_counters["ground_truth_in"] += 1
        if self.on_ground_truth is not None:
            self.on_ground_truth(msg)

    def _errors(self) -> int:
        return self.vloc_stage.errors + self.fusion_stage.errors

    # ------------------------------------------------------------------ vloc thread
    def _handle_frame(self, frame: RgbdFrame | EncodedRgbdFrame) -> None:
        res = self._vloc(frame)
        try:
            self.results.put(res)
            self.progress.result_put(bool(res.accepted))
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
        """Realtime, after an accepted fix: wait at most `prior_wait_ms` for fusion to take it, so
        the next frame's prior holds it (`Progress.await_previous_fix`). Timeouts are counted."""
        if self.params.mode == "realtime" and not self.progress.await_previous_fix(self.params.prior_wait_ms):
            self.shell_counters["prior_waits_timed_out"] += 1

    # ------------------------------------------------------------------ fusion thread
    def _handle_odometry_item(self, item: tuple[int, Odometry]) -> None:
        t_in, odom = item
        self._last_odom_wall = time.monotonic()
        try:
            for out in self.core.odometry(odom, t_in):
                self._out(out)
            self.core.after_odometry()  # work the pose must not wait for (deferred fusion update)
        finally:
            self.progress.odometry_handled()

    def _handle_result(self, res: VlocOutcome) -> None:
        try:
            for out in self.core.vloc_result(res):
                self._out(out)
        finally:
            self.progress.result_handled()

    # ------------------------------------------------------------------ publisher thread
    def _handle_publish(self, out: CoreOutput) -> None:
        """Hand one of the core's outputs to the publisher as it is (the core decided what goes out)."""
        pub, c = self.publisher, self.shell_counters
        if isinstance(out, PoseOut):
            if pub is not None:
                pub.publish_pose(out.t_ns, out.T_map_base, out.covariance)
            c["poses_published"] += 1
            self.e2e.add_since(out.t_in_ns)
        elif isinstance(out, MapToOdomOut):
            if pub is not None:
                pub.publish_map_to_odom(out.t_ns, out.T_map_odom)
            c["map_to_odom_published"] += 1
        elif isinstance(out, VlocOut):
            if pub is not None:
                pub.publish_vloc(out.t_ns, out.T_map_camera, out.covariance)
            c["vloc_published"] += 1

    # ------------------------------------------------------------------ sequential baseline
    def step(self, msg: SourceMessage) -> None:
        """One source message handled to completion in the calling thread, its outputs published."""
        if isinstance(msg, Odometry):
            self.shell_counters["odometry_in"] += 1
            self._handle_odometry_item((now_ns(), msg))
        elif isinstance(msg, RgbdFrame | EncodedRgbdFrame):
            self.shell_counters["frames_in"] += 1
            self._handle_result(self._vloc(msg))
        elif isinstance(msg, GroundTruthPose):
            self._ground_truth(msg)
        while self.outbox.ready():  # publish inline
            self._handle_publish(self.outbox.get_nowait())

    # ------------------------------------------------------------------ status
    def status_tick(self) -> None:
        """Build the status and publish it."""
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
        return build_status(self)

    def liveness(self) -> Liveness:
        """How long since the run started and since the last odometry message and camera frame."""
        now = time.monotonic()
        return Liveness(not self._stop.is_set() and self.source_stage.state == StageState.RUNNING,
                        now - self._t_start, None if self._last_odom_wall is None else now - self._last_odom_wall,
                        None if self._last_frame_wall is None else now - self._last_frame_wall, self._fatal)

    @property
    def queues(self) -> tuple[QueueBase[Any], ...]:
        return (self.frames, self.odometry, self.results, self.outbox)


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

