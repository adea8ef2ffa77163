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
from litevloc.pipelines.localization.tracking import TrackingState
from litevloc.runtime.service.queues import DropQueue

log = logging.getLogger(__name__)

# the state plot's value per state (GLOBAL: the localizer only); anything else plots as UNKNOWN_STATE_CODE
STATE_CODES: dict[str, int] = {s: code for code, s in enumerate(TrackingState)}
UNKNOWN_STATE_CODE = len(STATE_CODES)


# The view thread's Linux nice: VLoc's (runtime.vloc_nice). Lower priority would be worse: a
# view thread preempted while it holds the GIL stalls the fusion thread (fused-pose p99 x3 at 19).
VIEW_NICE = 10


class ViewError(LiteVLocError, RuntimeError):
    """The view could not be started (Rerun missing, no viewer can be spawned, bad path)."""


def _quat_xyzw(R: NDArray[np.float64]) -> NDArray[np.float64]:
    from litevloc.base.geometry import matrix_to_quat_xyzw

    return np.asarray(matrix_to_quat_xyzw(np.asarray(R, dtype=np.float64)), dtype=np.float64)


def covariance_ellipsoid(T_map_camera: NDArray[np.float64], covariance: NDArray[np.float64] | None,
                         sigma: float = 3.0) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
    """Half sizes (3,) and rotation (3x3, map frame) of the `sigma` position ellipsoid.

    `covariance`: 6x6 of a right (camera-frame) perturbation, order (tx, ty, tz, rx, ry, rz),
    as `pipelines.pnp` gives it; its translation block is rotated into the map frame."""
    if covariance is None:
        return None
    c = np.asarray(covariance, dtype=np.float64).reshape(6, 6)[:3, :3]
    if not np.all(np.isfinite(c)):
        return None
    R = np.asarray(T_map_camera, dtype=np.float64)[:3, :3]
    w, v = np.linalg.eigh(R @ c @ R.T)
    if np.linalg.det(v) < 0:
        v[:, 0] = -v[:, 0]
    return sigma * np.sqrt(np.clip(w, 0.0, None)), v


def occupied_points(grid: Any, height: float = 0.0) -> NDArray[np.float64]:
    """(N, 3) map-frame centres of the grid's occupied cells, `height` metres along its `up`."""
    rc = np.argwhere(np.asarray(grid.cells) == grid.OCCUPIED)
    if len(rc) == 0:
        return np.zeros((0, 3))
    xy = np.asarray(grid.origin, dtype=np.float64) + (rc[:, ::-1] + 0.5) * float(grid.resolution)
    axes = np.asarray(grid.plane_axes, dtype=np.float64)
    return np.asarray(xy @ axes + height * np.asarray(grid.up, dtype=np.float64), dtype=np.float64)


def _resized(color: NDArray[np.uint8], max_width: int) -> NDArray[np.uint8]:
    import cv2

    img: NDArray[np.uint8] = np.asarray(color)
    if img.shape[1] > max_width:
        s = max_width / img.shape[1]
        img = np.asarray(cv2.resize(img, (max_width, round(img.shape[0] * s)), interpolation=cv2.INTER_AREA))
    return img


def _encode_jpeg(rgb: NDArray[np.uint8]) -> bytes:
    import cv2

    ok, buf = cv2.imencode(".jpg", np.ascontiguousarray(rgb[..., ::-1]), [cv2.IMWRITE_JPEG_QUALITY, 80])
    if not ok:
        raise ValueError("JPEG encoding of a view image failed")
    return bytes(buf)


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
        # the trail as a ring of positions (no per-point Python objects to gather when it is logged)
        self._trail = np.zeros((max(trail_points, 2), 3))
        self._trail_n = 0
        self.image_width = image_width
        self.nice = nice
        self.topomap = topomap
        self.T_base_camera = np.eye(4) if T_base_camera is None else np.asarray(T_base_camera, dtype=np.float64)
        self.logged = {"fused": 0, "vloc": 0, "status": 0}
        self.errors = 0
        self.last_error: str | None = None
        self._last_pose_put: int | None = None
        self._last_state: tuple[str, str] | None = None
        self._last_plan: tuple[str, str, str] | None = None
        self._kf_resized: dict[tuple[int, int], NDArray[np.uint8]] = {}
        self._trail_logged_ns: int | None = None
        self.rec = rr.RecordingStream(application_id)
        sinks: list[Any] = []
        try:
            if spawn:
                self.rec.spawn(connect=False)
                sinks.append(rr.GrpcSink())
            if self.save_path is not None:
                sinks.append(rr.FileSink(str(self.save_path)))
            self.rec.set_sinks(*sinks, default_blueprint=self.blueprint())
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
                self._log_map(self.topomap)
        except Exception as exc:
            self._error(exc)
        while True:
            stopping = self._stop.is_set()
            for item in self.queue.get_all(0.1):
                try:
                    self._handle(item)
                except Exception as exc:  # a bad item must not end the view (nor the service)
                    self._error(exc)
            if stopping:
                return

    def _error(self, exc: Exception) -> None:
        self.errors += 1
        self.last_error = f"{type(exc).__name__}: {exc}"
        if self.errors <= 3:
            log.warning("view: %s", self.last_error)

    def _handle(self, item: tuple[Any, ...]) -> None:
        kind = item[0]
        if kind == "fused":
            self._log_fused(item[1], item[2])
        elif kind == "vloc":
            self._log_vloc(item[1], item[2])
        elif kind == "status":
            self._log_status(item[1])
        elif kind == "plan":
            self._log_plan(item[1])
        self.logged[kind] = self.logged.get(kind, 0) + 1

    def _log(self, path: str, *args: Any, **kwargs: Any) -> None:
        """One Rerun log call, then the GIL handed over: a thread waiting for it (fusion) gets it
        now instead of at the interpreter's next switch interval (5 ms), so a burst of view
        work never holds the GIL for more than one call."""
        self.rec.log(path, *args, **kwargs)
        time.sleep(0)

    def _time(self, t_ns: int) -> None:
        self.rec.set_time("sensor_time", duration=t_ns * 1e-9)

    def _log_pose(self, path: str, T: NDArray[np.float64], static: bool = False) -> None:
        T = np.asarray(T, dtype=np.float64)
        self._log(path, self.rr.Transform3D(translation=T[:3, 3],
                                                 quaternion=self.rr.Quaternion(xyzw=_quat_xyzw(T[:3, :3]))),
                     static=static)

    def _pinhole(self, K: NDArray[np.float64], size: tuple[int, int], color: tuple[int, int, int],
                 distance: float = 0.25) -> Any:
        return self.rr.Pinhole(image_from_camera=np.asarray(K, dtype=np.float64), resolution=[size[0], size[1]],
                               camera_xyz=self.rr.ViewCoordinates.RDF, image_plane_distance=distance, color=color)

    def _log_map(self, m: Any) -> None:
        rr = self.rr
        P = np.asarray(m.positions, dtype=np.float64)
        for i in range(m.n_nodes):
            self._log_pose(f"world/map/keyframes/{i}", m.T_map_camera[i], static=True)
            w, h = (int(v) for v in m.image_size[i])
            self._log(f"world/map/keyframes/{i}", self._pinhole(m.K[i], (w, h), (150, 150, 150), 0.15),
                         static=True)
        self._log("world/map/keyframe_ids", rr.Points3D(P, radii=0.02, colors=(200, 200, 200),
                                                           labels=[str(i) for i in range(m.n_nodes)],
                                                           show_labels=False), static=True)
        if len(m.covis_edges):
            self._log("world/map/covisibility", rr.LineStrips3D(P[np.asarray(m.covis_edges)], radii=0.004,
                                                                   colors=(160, 160, 160)), static=True)
        if len(m.conn_edges):
            self._log("world/map/connectivity", rr.LineStrips3D(P[np.asarray(m.conn_edges)], radii=0.012,
                                                                   colors=(60, 120, 255)), static=True)
        occ = occupied_points(m.grid)
        if len(occ):
            self._log("world/map/occupancy", rr.Points3D(occ, radii=float(m.grid.resolution) / 2,
                                                            colors=(220, 70, 70)), static=True)
        self._log("world/map/info", rr.TextDocument(
            f"map: {m.n_nodes} keyframes, {len(m.covis_edges)} covisibility and {len(m.conn_edges)} "
            "connectivity edges"), static=True)

    def _log_fused(self, t_ns: int, T_map_base: NDArray[np.float64]) -> None:
        rr = self.rr
        self._time(t_ns)
        T = np.asarray(T_map_base, dtype=np.float64) @ self.T_base_camera
        self._log_pose("world/fused", T)
        self._log("world/fused", rr.TransformAxes3D(axis_length=0.3) if hasattr(rr, "TransformAxes3D")
                     else rr.Points3D([[0.0, 0.0, 0.0]], radii=0.05))
        cap = len(self._trail)
        self._trail[self._trail_n % cap] = T[:3, 3]
        self._trail_n += 1
        if self._trail_n >= 2 and (self._trail_logged_ns is None or t_ns - self._trail_logged_ns >= 1_000_000_000):
            self._trail_logged_ns = t_ns
            k = self._trail_n % cap
            trail = self._trail[:self._trail_n] if self._trail_n <= cap else np.roll(self._trail, -k, axis=0)
            self._log("world/fused_trail", rr.LineStrips3D([trail], radii=0.01,
                                                              colors=(40, 200, 80)))

    def _log_vloc(self, frame: Any, res: Any) -> None:
        rr = self.rr
        t_ns = int(getattr(res, "t_ns", frame.t_ns))
        self._time(t_ns)
        color = np.asarray(frame.color)
        h, w = color.shape[:2]
        live_small = _resized(color, self.image_width)
        jpeg = _encode_jpeg(live_small)
        for k in ("extract", "vpr", "match", "pnp", "total"):
            v = (getattr(res, "timings_ms", None) or {}).get(k)
            if v is not None:
                self._log(f"plots/vloc_ms/{k}", rr.Scalars(float(v)))
        accepted = bool(getattr(res, "accepted", False)) and getattr(res, "T_map_camera", None) is not None
        ref = int(getattr(res, "ref_node", -1))
        info = (f"{'ACCEPTED' if accepted else 'rejected'} ({getattr(res, 'mode', '?')}): "
                f"{getattr(res, 'reason', '')}\n\nreference keyframe {ref if ref >= 0 else '-'}; "
                f"{getattr(res, 'n_matches', 0)} matches, {getattr(res, 'n_inliers', 0)} PnP inliers "
                f"(ratio {float(getattr(res, 'inlier_ratio', 0.0)):.2f}), median reprojection "
                f"{float(getattr(res, 'median_reprojection_px', float('nan'))):.2f} px\n\n"
                "matches with the reference keyframe (live image | keyframe): inliers green, outliers red")
        self._log("images/match_info", rr.TextDocument(info))
        self._log("status/vloc", rr.TextLog(info.split("\n")[0], level="INFO" if accepted else "WARN"))
        self._log("plots/vloc_inliers", rr.Scalars(float(getattr(res, "n_inliers", 0))))
        m = self.topomap
        has_ref = m is not None and 0 <= ref < m.n_nodes
        self._log_matches(getattr(res, "matches", None) if has_ref else None, live_small, jpeg, w, ref)
        if m is not None and has_ref:
            self._log_pose("world/vloc/reference", m.T_map_camera[ref])
            rw, rh = (int(v) for v in m.image_size[ref])
            self._log("world/vloc/reference", self._pinhole(m.K[ref], (rw, rh), (255, 150, 0), 0.3))
        if accepted:
            T = np.asarray(res.T_map_camera, dtype=np.float64)
            self._log_pose("world/vloc/camera", T)
            self._log("world/vloc/camera", self._pinhole(frame.K, (w, h), (0, 220, 0), 0.3))
            self._log("world/vloc/camera", rr.EncodedImage(contents=jpeg, media_type="image/jpeg"))
            ell = covariance_ellipsoid(T, getattr(res, "covariance", None))
            if ell is not None:
                half, Rm = ell
                self._log("world/vloc/covariance", rr.Ellipsoids3D(
                    centers=[T[:3, 3]], half_sizes=[half], quaternions=[_quat_xyzw(Rm)], colors=(0, 220, 0),
                    labels=["3-sigma"]))

    def _log_plan(self, st: Mapping[str, Any]) -> None:
        """The planner's node path (orange strip through the keyframe positions) and its subgoal."""
        rr = self.rr
        t = st.get("pose_t_ns")
        if t is not None:
            self._time(int(t))
        m = self.topomap
        path = [int(n) for n in st.get("path") or []]
        if m is not None and len(path) >= 2 and all(0 <= n < m.n_nodes for n in path):
            self._log("world/plan/path", rr.LineStrips3D([np.asarray(m.positions, dtype=np.float64)[path]],
                                                            radii=0.03, colors=(255, 140, 0)))
        else:
            self._log("world/plan/path", rr.Clear(recursive=False))
        sub = st.get("subgoal_node")
        if m is not None and sub is not None and 0 <= int(sub) < m.n_nodes:
            self._log("world/plan/subgoal", rr.Points3D([m.positions[int(sub)]], radii=0.08, colors=(255, 60, 200),
                                                           labels=[f"subgoal {int(sub)}"]))
        key = (str(st.get("state")), str(st.get("goal")), str(st.get("reason")))
        if key != self._last_plan:
            self._last_plan = key
            level = "ERROR" if key[0] == "failed" else "INFO"
            self._log("status/planner", rr.TextLog(f"planner {key[0]}: goal {key[1]}: {key[2]}", level=level))

    def _keyframe_at_height(self, ref: int, width: int, height: int) -> NDArray[np.uint8]:
        """The keyframe's stored JPEG decoded (RGB) and resized to width x height; the last 32
        kept (tracking reuses a few keyframes)."""
        import cv2

        img = self._kf_resized.get((ref, height))
        if img is None:
            bgr = cv2.imdecode(np.frombuffer(self.topomap.images_jpeg[ref], np.uint8), cv2.IMREAD_COLOR)
            if bgr is None:
                raise ValueError(f"keyframe {ref}'s image does not decode")
            img = np.asarray(cv2.resize(np.ascontiguousarray(bgr[:, :, ::-1]), (width, height),
                                        interpolation=cv2.INTER_AREA))
            if len(self._kf_resized) >= 32:
                self._kf_resized.pop(next(iter(self._kf_resized)))
            self._kf_resized[(ref, height)] = img
        return img

    def _log_matches(self, matches: Any, live_small: NDArray[np.uint8], live_jpeg: bytes, live_width: int,
                     ref: int) -> None:
        """`images/matches`: the live image and the matched keyframe side by side at one height,
        each match a segment between them, inliers green, outliers red (the classic match view);
        a rejected result shows the live image alone (`live_jpeg`, already encoded)."""
        rr = self.rr
        h1, w1 = live_small.shape[:2]
        s1 = w1 / live_width
        if matches is None or int(getattr(matches, "keyframe", -1)) != ref:
            self._log("images/matches", rr.EncodedImage(contents=live_jpeg, media_type="image/jpeg"))
            self._log("images/matches/lines", rr.Clear(recursive=False))
            return
        kw, kh = (int(v) for v in self.topomap.image_size[ref])  # the keyframe's pixel frame
        s2 = h1 / kh
        kf = self._keyframe_at_height(ref, max(1, round(kw * s2)), h1)
        composite = np.concatenate([live_small, kf], axis=1)
        self._log("images/matches", rr.EncodedImage(contents=_encode_jpeg(composite), media_type="image/jpeg"))
        a = np.asarray(matches.live_px, dtype=np.float32).reshape(-1, 2)
        b = np.asarray(matches.keyframe_px, dtype=np.float32).reshape(-1, 2)
        inl = np.asarray(matches.inlier, dtype=bool).reshape(-1)
        colors = np.where(inl[:, None], np.array([[40, 220, 60]], np.uint8), np.array([[230, 40, 40]], np.uint8))
        segs = np.stack([a * s1, b * s2 + np.array([w1, 0.0], np.float32)], axis=1)
        self._log("images/matches/lines", rr.LineStrips2D(segs, colors=colors, radii=0.6))
        self.logged["matches"] = self.logged.get("matches", 0) + len(a)

    def _log_status(self, st: Mapping[str, Any]) -> None:
        rr = self.rr
        t = st.get("sensor_time_ns")
        if t is not None:
            self._time(int(t))
        state = str(st.get("state", TrackingState.INIT))
        reasons = "; ".join(str(r) for r in st.get("reasons") or [])
        self._log("plots/state", rr.Scalars(float(STATE_CODES.get(state, UNKNOWN_STATE_CODE))))
        if (state, reasons) != self._last_state:
            self._last_state = (state, reasons)
            levels: dict[str, str] = {TrackingState.TRACKING: "INFO", TrackingState.INIT: "WARN",
                                      TrackingState.GLOBAL: "WARN"}
            level = levels.get(state, "ERROR")
            self._log("status/tracking", rr.TextLog(f"{state}" + (f": {reasons}" if reasons else ""),
                                                       level=level))
        stages = st.get("stages") or {}
        series = {
            "fusion_p99": ((stages.get("fusion") or {}).get("latency", {}).get("odometry") or {}).get("p99_ms"),
            "publish_p99": ((stages.get("publisher") or {}).get("latency", {}).get("outbox") or {}).get("p99_ms"),
            "odometry_to_publish_p99": ((st.get("latency") or {}).get("odometry_to_publish") or {}).get("p99_ms"),
        }
        for k, v in series.items():
            if v is not None and np.isfinite(float(v)):
                self._log(f"plots/runtime_ms/{k}", rr.Scalars(float(v)))
        for name, q in (st.get("queues") or {}).items():
            self._log(f"plots/queues/{name}", rr.Scalars(float(q.get("depth") or 0)))
        self._log("plots/view_drops", rr.Scalars(float(self.queue.drops)))

    # ------------------------------------------------------------------ layout, end
    def blueprint(self) -> Any:
        rrb = self.rrb
        return rrb.Blueprint(
            rrb.Horizontal(
                rrb.Spatial3DView(origin="world", name="map, fused pose, VLoc"),
                rrb.Vertical(
                    rrb.Spatial2DView(origin="images/matches",
                                      name="live image | matched keyframe (inliers green, outliers red)"),
                    rrb.Horizontal(rrb.TextDocumentView(origin="images/match_info", name="VLoc result"),
                                   rrb.TextLogView(origin="status", name="tracking state / VLoc")),
                    rrb.Horizontal(rrb.TimeSeriesView(origin="plots/vloc_ms", name="VLoc stages (ms)"),
                                   rrb.TimeSeriesView(origin="plots/runtime_ms", name="runtime p99 (ms)")),
                ),
                column_shares=[3, 2],
            ),
            collapse_panels=True,
        )

    def report(self) -> dict[str, Any]:
        return {"queued": self.queue.puts, "dropped": self.queue.drops, "logged": dict(self.logged),
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
