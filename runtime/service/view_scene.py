"""What the live view draws (`runtime.service.view`): each queued item as Rerun log calls, in
the view thread only. Entity paths and colours: see `runtime.service.view`'s docstring."""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
from numpy.typing import NDArray

from litevloc.pipelines.localization.tracking import TrackingState

# the state plot's value per state (GLOBAL: the localizer only); anything else plots as UNKNOWN_STATE_CODE
STATE_CODES: dict[str, int] = {s: code for code, s in enumerate(TrackingState)}
UNKNOWN_STATE_CODE = len(STATE_CODES)


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


def blueprint(rrb: Any) -> Any:
    """The viewer's layout: the 3D world beside the match image, the VLoc text and the plots."""
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


class Scene:
    """Turns the view's items into log calls on the recording `rec` (module `rr` is rerun).

    `topomap` (optional) gives the keyframes (logged once by `log_map`), `T_base_camera` places the
    fused camera, `trail_points` bounds the fused trail, `image_width` the logged live image;
    `drops()` is the view queue's drop count (plotted). `logged` counts what was drawn per kind."""

    def __init__(self, rr: Any, rec: Any, topomap: Any, T_base_camera: NDArray[np.float64], trail_points: int,
                 image_width: int, drops: Callable[[], int]) -> None:
        self.rr, self.rec, self.topomap, self.T_base_camera = rr, rec, topomap, T_base_camera
        self.image_width, self._drops = image_width, drops
        # the trail as a ring of positions (no per-point Python objects to gather when it is logged)
        self._trail = np.zeros((max(trail_points, 2), 3))
        self._trail_n = 0
        self.logged = {"fused": 0, "vloc": 0, "status": 0}
        self._last_state: tuple[str, str] | None = None
        self._last_map: tuple[Any, ...] | None = None
        self._last_plan: tuple[str, str, str] | None = None
        self._kf_resized: dict[tuple[int, int], NDArray[np.uint8]] = {}
        self._trail_logged_ns: int | None = None

    def handle(self, item: tuple[Any, ...]) -> None:
        """One queued item: ("fused", t_ns, T_map_base), ("vloc", frame, result), ("status", st), ("plan", st)."""
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

    def log_map(self, m: Any) -> None:
        """The map as static data: keyframe frustums, edges, occupied cells, a summary."""
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

    def _log_map_status(self, m: Mapping[str, Any] | None) -> None:
        """The map in use and its switches (the status's `map` entry), logged when they change."""
        if not m:
            return
        key = (m.get("map_id"), m.get("version"), m.get("switches"), m.get("refusals"))
        if key == self._last_map:
            return
        self._last_map = key
        text = f"map {m.get('name')}@{m.get('version')} ({m.get('map_id')}), {m.get('switches')} switch(es)"
        refused = bool(m.get("refused_since_switch"))
        if refused:
            text += f"; version {m.get('last_refused_version')} refused: {m.get('last_refusal')}"
        self._log("status/map", self.rr.TextLog(text, level="WARN" if refused else "INFO"))

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
        self._log_map_status(st.get("map"))
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
        self._log("plots/view_drops", rr.Scalars(float(self._drops())))
