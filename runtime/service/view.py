"""The live view (`--view`, `--view-save FILE`): what the localizer sees, streamed to Rerun.

Off the hot path: producers (the VLoc thread, the fusion thread, the status tick, or the
`localize` loop) only `put` a small tuple into a bounded latest-value queue (`DropQueue`;
the oldest item is dropped when it is full, counted, never blocking); one view thread
(at VLoc's nice, 10) turns items into Rerun log calls. Fused poses are thinned at the producer
to `pose_hz` of sensor time before they are queued. Rerun is imported only when a
`LiveView` is made, so nothing extra is imported with the view off.

Shown (entity paths; timeline `sensor_time` in seconds of sensor time):

* `world/map/keyframes/<i>`: each keyframe's camera frustum (pose + pinhole);
  `world/map/covisibility` (grey) and `world/map/connectivity` (blue) edges;
  `world/map/occupancy`: occupied cells (red) of the map's grid, on the grid's plane.
* `world/fused` the fused camera pose (`T_map_base @ T_base_camera`) and
  `world/fused_trail` its trail (last `trail_points` positions).
* `world/vloc/camera` each VLoc result (accepted: green frustum with the live image on it;
  rejected: nothing moves), `world/vloc/covariance` the 3-sigma position ellipsoid (map
  frame), `world/vloc/reference` the reference keyframe's frustum highlighted (orange).
* `images/matches` the live image and the matched keyframe side by side with each match
  drawn as a segment (`images/matches/lines`: inliers green, outliers red; from the
  result's `MatchedPixels`; a rejected result: the live image alone);
  `images/match_info` the counts, inlier ratio and reprojection error.
* `status/tracking` the tracking state and reasons as a text log (on every change) and
  `plots/state` (0 INIT, 1 GLOBAL, 2 TRACKING, 3 LOST, 4 FAILED); `status/vloc` each VLoc outcome.
* `plots/vloc_ms/<stage>` extract / vpr / match / pnp / total per query;
  `plots/runtime_ms/<name>` fusion / publish / odometry-to-publish p99 from the status;
  `plots/queues/<name>` queue depths; `plots/view_drops` items the view dropped.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from litevloc.base.errors import LiteVLocError
from litevloc.runtime.service.queues import DropQueue
from litevloc.runtime.service.view_scene import Scene, blueprint

log = logging.getLogger(__name__)

# The view thread's Linux nice: VLoc's (runtime.vloc_nice). Lower priority would be worse: a
# view thread preempted while it holds the GIL stalls the fusion thread (fused-pose p99 x3 at 19).
VIEW_NICE = 10


class ViewError(LiteVLocError, RuntimeError):
    """The view could not be started (Rerun missing, no viewer can be spawned, bad path)."""


class LiveView:
    """Rerun recording fed from a bounded queue by one view thread (see the module docstring).

    `spawn`: start the Rerun viewer (native; needs a display) and stream to it. `save`:
    write the stream to this `.rrd` file (opened later with `rerun FILE` or the web viewer).
    At least one of them. `T_base_camera` places the fused camera; `topomap` (optional) is
    logged once as static data."""

    def __init__(self, *, save: Path | None = None, spawn: bool = False, topomap: Any = None,
                 T_base_camera: NDArray[np.float64] | None = None, queue_capacity: int = 256,
                 pose_hz: float = 20.0, trail_points: int = 2000, image_width: int = 320, nice: int = VIEW_NICE,
                 application_id: str = "litevloc") -> None:
        if save is None and not spawn:
            raise ViewError("the view needs a viewer to spawn (--view) or a file to save (--view-save)")
        try:
            import rerun as rr
            import rerun.blueprint as rrb
        except ImportError as exc:
            raise ViewError("the live view needs the `rerun-sdk` package: pip install 'litevloc[view]'") from exc
        self.rr, self.rrb = rr, rrb
        self.save_path = None if save is None else Path(save)
        if self.save_path is not None:
            self.save_path.parent.mkdir(parents=True, exist_ok=True)
        self.queue = DropQueue(queue_capacity)
        self.pose_period_ns = int(1e9 / pose_hz) if pose_hz > 0 else 0
        self.nice = nice
        self.topomap = topomap
        self.errors = 0
        self.last_error: str | None = None
        self._last_pose_put: int | None = None
        self.rec = rr.RecordingStream(application_id)
        T_bc = np.eye(4) if T_base_camera is None else np.asarray(T_base_camera, dtype=np.float64)
        self.scene = Scene(rr, self.rec, topomap, T_bc, trail_points, image_width, lambda: self.queue.drops)
        sinks: list[Any] = []
        try:
            if spawn:
                self.rec.spawn(connect=False)
                sinks.append(rr.GrpcSink())
            if self.save_path is not None:
                sinks.append(rr.FileSink(str(self.save_path)))
            self.rec.set_sinks(*sinks, default_blueprint=blueprint(rrb))
        except Exception as exc:
            raise ViewError(f"cannot start the Rerun view: {exc}") from exc
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._main, name="litevloc-view", daemon=True)
        self._thread.start()

    # ------------------------------------------------------------------ producer side (hot path: cheap)
    def put_fused(self, fused: Any) -> None:
        """From the fusion thread (anything with t_ns, T_map_base, initialised); thinned to pose_hz."""
        if not getattr(fused, "initialised", True):
            return
        t = int(fused.t_ns)
        if self._last_pose_put is not None and t - self._last_pose_put < self.pose_period_ns:
            return
        self._last_pose_put = t
        self.queue.put(("fused", t, fused.T_map_base))

    def put_vloc(self, frame: Any, result: Any) -> None:
        """From the VLoc thread: the frame (t_ns, color, K) and its LocalizationResult."""
        self.queue.put(("vloc", frame, result))

    def put_status(self, status: Mapping[str, Any]) -> None:
        """From the status tick: the service's status snapshot."""
        self.queue.put(("status", status))

    def put_plan(self, status: Mapping[str, Any]) -> None:
        """From the planner's status (`litevloc/plan/status` JSON): goal, state, node path, subgoal."""
        self.queue.put(("plan", status))

    def wrap_vloc(self, fn: Callable[[Any, Any], Any]) -> Callable[[Any, Any], Any]:
        """`vloc(frame, prior)` that also hands (frame, result) to the view."""

        def vloc(frame: Any, prior: Any) -> Any:
            res = fn(frame, prior)
            self.put_vloc(frame, res)
            return res

        return vloc

    # ------------------------------------------------------------------ view thread
    def _main(self) -> None:
        from litevloc.runtime.service.stages import lower_thread_priority

        lower_thread_priority(self.nice)
        try:
            if self.topomap is not None:
                self.scene.log_map(self.topomap)
        except Exception as exc:
            self._error(exc)
        while True:
            stopping = self._stop.is_set()
            for item in self.queue.get_all(0.1):
                try:
                    self.scene.handle(item)
                except Exception as exc:  # a bad item must not end the view (nor the service)
                    self._error(exc)
            if stopping:
                return

    def _error(self, exc: Exception) -> None:
        self.errors += 1
        self.last_error = f"{type(exc).__name__}: {exc}"
        if self.errors <= 3:
            log.warning("view: %s", self.last_error)

    # ------------------------------------------------------------------ end
    def report(self) -> dict[str, Any]:
        return {"queued": self.queue.puts, "dropped": self.queue.drops, "logged": dict(self.scene.logged),
                "errors": self.errors, "last_error": self.last_error,
                "saved": None if self.save_path is None else str(self.save_path)}

    def close(self, timeout_s: float = 30.0) -> dict[str, Any]:
        """Log what is queued, end the thread, flush the sinks (the .rrd is complete after this)."""
        self._stop.set()
        self.queue._ready.set()
        self._thread.join(timeout_s)
        with contextlib.suppress(Exception):
            self.rec.flush(timeout_sec=timeout_s)
        with contextlib.suppress(Exception):
            self.rec.disconnect()
        t0 = time.monotonic()
        while self.save_path is not None and not self.save_path.exists() and time.monotonic() - t0 < 5:
            time.sleep(0.05)
        return self.report()
