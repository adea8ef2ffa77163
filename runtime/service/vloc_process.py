"""VLoc in a child process: the service's `vloc(frame, prior)` with the work done elsewhere.

In one process the VLoc thread's Python glue (numpy, OpenCV calls, the localizer's own
code) holds the GIL, and a niced GIL holder that the kernel preempts makes the fusion
thread wait for the GIL, not for a core (priority inversion): measured, this is most of the
fused-pose p99 (`bench/runtime.py`). Here the localizer (models, map) lives in a child
process at the VLoc priority (`runtime.vloc_nice`); the service's VLoc thread only sends the
frame and the prior down a pipe and waits for the result (no GIL, no CPU while it waits).
Fusion, publishing and the source keep the parent's GIL to themselves.

```
parent VLoc thread --(frame, prior)--> pipe --> child: VisualLocalizer.process
                   <----(result)------ pipe <--
```

* `VlocProcess(spec)` starts the child (spawn: a fresh interpreter, never a fork of a
  process with Zenoh and GTSAM threads) and waits until it has loaded the models and the map,
  so a missing model or a bad map is raised here, before any service thread starts, as the
  same one-line user error the in-process path gives.
* `__call__(frame, prior)` -> the `LocalizationResult` (with the localizer's tracking state),
  computed in the child. An exception in the child's query comes back as `VlocProcessError`
  carrying its traceback summary (the VLoc stage counts it as it counts an in-process one); a
  child that died is `VlocProcessError` naming its exit code, on this and every later call.
* `prepare_map(path)` / `commit_map()` / `discard_map()` (`runtime.service.map_switch`): the child
  loads and checks a new map version in a thread of its own while it answers queries (the parent
  polls it), and switches to it between two queries when told.
* `close()` asks the child to end, then terminates it after `join_timeout_s`. The child ignores
  SIGINT/SIGTERM (a terminal's Ctrl-C or systemd reaches the whole process group: the parent
  decides when VLoc ends) and ends by itself when the parent's end of the pipe closes; one left
  running at exit is killed (`runtime.child_processes`).

The pipe carries pickles between two processes of this program only (multiprocessing's
`Connection`); nothing a user hands us is unpickled.
"""

from __future__ import annotations

import contextlib
import logging
import multiprocessing
import os
import signal
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from litevloc.base.errors import LiteVLocError
from litevloc.runtime.child_processes import end_child, start_child

if TYPE_CHECKING:
    from multiprocessing.connection import Connection

    from litevloc.config.schema import LiteVLocConfig
    from litevloc.hw.messages import RgbdFrame
    from litevloc.models.ort import ProviderReport
    from litevloc.runtime.service.core import VlocOutcome
    from litevloc.runtime.service.map_versions import ThreadVloc
    from litevloc.runtime.service.vloc_prior import VlocPrior

log = logging.getLogger(__name__)


class VlocProcessError(LiteVLocError, RuntimeError):
    """The VLoc child process could not start, failed a query, or died; the message says which."""


@dataclass(frozen=True)
class VlocWorkerSpec:
    """What the child needs to build the localizer as `runtime.service.app.build_app` does."""

    config: LiteVLocConfig
    map_path: Path
    start_timeout_s: float = 120.0  # model and map loading
    join_timeout_s: float = 5.0


class _ChildMaps:
    """The child's side of a map switch: `prepare` loads a version in a thread of the child (the
    queries go on), `poll` says how far it got, `commit` switches between two queries (the
    parent's `VlocProcess.prepare_map` / `commit_map`)."""

    def __init__(self, vloc: ThreadVloc) -> None:
        self.vloc = vloc
        self.state: tuple[Any, ...] = ("idle",)
        self._lock = threading.Lock()

    def _prepare(self, path: Path) -> None:
        from litevloc.runtime.service.map_versions import MapRefusal, MapRefused

        try:
            state: tuple[Any, ...] = ("prepared", self.vloc.prepare_map(path))
        except MapRefused as exc:
            state = ("refused", exc.kind.value, str(exc))
        except Exception as exc:
            state = ("refused", MapRefusal.LOAD_FAILED.value, f"{type(exc).__name__}: {exc}")
        with self._lock:
            self.state = state

    def command(self, msg: tuple[Any, ...]) -> tuple[Any, ...]:
        kind = msg[0]
        if kind == "prepare":
            with self._lock:
                self.state = ("pending",)
            threading.Thread(target=self._prepare, args=(Path(msg[1]),), name="map-load", daemon=True).start()
            return ("preparing",)
        if kind == "poll":
            with self._lock:
                return self.state
        if kind in ("commit", "discard"):
            (self.vloc.commit_map if kind == "commit" else self.vloc.discard_map)()
            with self._lock:
                self.state = ("idle",)
            return ("done",)
        return ("raised", f"unknown command {kind!r}")


def _worker_main(spec: VlocWorkerSpec, conn: Connection) -> None:
    """The child: load models and map, then answer `("frame", frame, prior)` until told to stop."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    try:
        import dataclasses

        from litevloc.pipelines.localization.vloc import VisualLocalizer
        from litevloc.pipelines.topomap.io import load_map
        from litevloc.runtime.service.map_versions import ThreadVloc
        from litevloc.runtime.service.stages import configure_threads, lower_thread_priority, traceback_summary
        from litevloc.runtime.vloc_models import check_map_models, load_bundle, second_look_for

        rt = spec.config.runtime
        nice = lower_thread_priority(rt.vloc_nice)  # the main thread, before any other starts: they inherit it
        configure_threads(rt.cv_threads, rt.ort_intra_op_threads, rt.ort_inter_op_threads)
        models = dataclasses.replace(spec.config.models, intra_op_threads=rt.ort_intra_op_threads)
        bundle = load_bundle(models)
        topomap = check_map_models(load_map(spec.map_path), bundle)
        lp = spec.config.localization
        localizer = VisualLocalizer(topomap, lp, bundle.extract, bundle.describe, bundle.match,
                                    second_look=second_look_for(topomap, models, lp, bundle))
        vloc = ThreadVloc(topomap, localizer, bundle, spec.config)
    except BaseException as exc:  # reported to the parent, which raises it as a user error
        conn.send(("error", type(exc).__name__, str(exc), isinstance(exc, LiteVLocError)))
        conn.close()
        return
    from litevloc.models.ort import provider_report

    conn.send(("ready", os.getpid(), nice, provider_report()))
    maps = _ChildMaps(vloc)
    while True:
        try:
            msg = conn.recv()
        except (EOFError, OSError):  # the parent is gone
            return
        if msg[0] == "stop":
            conn.close()
            return
        if msg[0] != "frame":
            reply: tuple[Any, ...] = maps.command(msg)
        else:
            _, frame, prior = msg
            try:
                reply = ("result", vloc(frame, prior))
            except Exception as exc:
                reply = ("raised", traceback_summary(exc))
        try:
            conn.send(reply)
        except (EOFError, OSError, BrokenPipeError):
            return


class VlocProcess:
    """`vloc(frame, prior) -> VlocOutcome` computed by a `VisualLocalizer` in a child process.

    One call at a time (the service's single VLoc thread); thread-safe anyway (a lock)."""

    def __init__(self, spec: VlocWorkerSpec) -> None:
        self.spec = spec
        self._conn, child = multiprocessing.get_context("spawn").Pipe(duplex=True)
        self._proc = start_child(_worker_main, (spec, child), "litevloc-vloc")
        child.close()  # the child's end lives in the child only: its exit closes the pipe here
        self._lock = threading.Lock()
        self._dead: str | None = None
        self.calls = 0
        self.child_nice: int | None = None
        self.provider_report: ProviderReport | None = None  # the child's models (`models.ort.provider_report`)
        self._await_ready()

    @property
    def pid(self) -> int | None:
        return self._proc.pid

    def _await_ready(self) -> None:
        deadline = time.monotonic() + self.spec.start_timeout_s
        while not self._conn.poll(0.1):
            if not self._proc.is_alive():
                self._proc.join(1.0)
                raise VlocProcessError(f"the VLoc process exited during start-up (exit code {self._proc.exitcode})")
            if time.monotonic() > deadline:
                self.close()
                raise VlocProcessError(f"the VLoc process did not load its models and map within "
                                       f"{self.spec.start_timeout_s:g} s")
        try:
            msg = self._conn.recv()
        except EOFError as exc:
            self._proc.join(1.0)
            raise VlocProcessError(f"the VLoc process exited during start-up (exit code {self._proc.exitcode})") \
                from exc
        if msg[0] == "error":
            _, kind, text, user_error = msg
            self._proc.join(self.spec.join_timeout_s)
            raise VlocProcessError(text if user_error else f"VLoc process start-up failed: {kind}: {text}")
        self.child_nice = msg[2]
        self.provider_report = msg[3]

    def __call__(self, frame: RgbdFrame, prior: VlocPrior | None) -> VlocOutcome:
        with self._lock:
            if self._dead is not None:
                raise VlocProcessError(self._dead)
            try:
                self._conn.send(("frame", frame, prior))
                msg = self._conn.recv()
            except (EOFError, OSError, BrokenPipeError) as exc:
                self._proc.join(1.0)
                self._dead = f"the VLoc process died (exit code {self._proc.exitcode})"
                raise VlocProcessError(self._dead) from exc
            self.calls += 1
        if msg[0] == "raised":
            raise VlocProcessError(f"VLoc query failed in the VLoc process: {msg[1]}")
        result: VlocOutcome = msg[1]
        return result

    def _command(self, msg: tuple[Any, ...]) -> tuple[Any, ...]:
        """One map command to the child and its reply; MapRefused (VLOC_PROCESS) if the child is gone."""
        from litevloc.runtime.service.map_versions import MapRefusal, MapRefused

        with self._lock:
            if self._dead is not None:
                raise MapRefused(MapRefusal.VLOC_PROCESS, self._dead)
            try:
                self._conn.send(msg)
                reply: tuple[Any, ...] = self._conn.recv()
            except (EOFError, OSError, BrokenPipeError) as exc:
                self._proc.join(1.0)
                self._dead = f"the VLoc process died (exit code {self._proc.exitcode})"
                raise MapRefused(MapRefusal.VLOC_PROCESS, self._dead) from exc
        if reply[0] == "raised":
            raise MapRefused(MapRefusal.VLOC_PROCESS, f"the VLoc process refused {msg[0]!r}: {reply[1]}")
        return reply

    def prepare_map(self, path: Path, poll_s: float = 0.05) -> int:
        """The child loads and verifies the version at `path` beside its map (queries go on
        meanwhile); its node count, or MapRefused (`map_versions.prepare_localizer`)."""
        from litevloc.runtime.service.map_versions import MapRefusal, MapRefused

        self._command(("prepare", str(path)))
        while True:
            time.sleep(poll_s)
            reply = self._command(("poll",))
            if reply[0] == "prepared":
                return int(reply[1])
            if reply[0] == "refused":
                raise MapRefused(MapRefusal(reply[1]), str(reply[2]))

    def commit_map(self) -> None:
        """The child switches to the prepared version (call between two queries)."""
        self._command(("commit",))

    def discard_map(self) -> None:
        self._command(("discard",))

    def close(self) -> None:
        """End the child (asked first, terminated after `join_timeout_s`); idempotent."""
        if self._proc.pid is None:
            return
        with self._lock:
            if self._proc.is_alive():
                with contextlib.suppress(OSError, BrokenPipeError):
                    self._conn.send(("stop",))
                self._proc.join(self.spec.join_timeout_s)
            if self._proc.is_alive():
                log.warning("VLoc process %s did not stop within %g s: terminating", self._proc.pid,
                            self.spec.join_timeout_s)
                end_child(self._proc, self.spec.join_timeout_s)
            self._conn.close()
            self._dead = self._dead or "the VLoc process was closed"
