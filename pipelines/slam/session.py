"""The mapping pass's SLAM put together: `SlamSession` takes odometry samples and frames in
time order, runs the front end and the loop search online, and `finish()` optimises the
graph and poses every frame (`SlamResult`, with its report).

Frames wait for the odometry to pass their stamp (they are posed by interpolation), or until
later messages show the odometry silent for `odometry.max_gap_s`; then they go to the front
end without an odometry pose (visual tracking bridges the gap).

The map frame: the first keyframe's base_link (through the configured `T_base_camera`) with
gravity up. Gravity comes from the odometry frame's z where the first keyframe has odometry
(wheel odometry on a floor: the odom frame is level; the map frame keeps the first keyframe's
heading), otherwise the first keyframe's base_link is taken as level (the camera mount of
the configuration on a level robot). The map frame is then turned so that gravity lies along
`mapping.up`. The report says which applied.

After the optimisation the walls in the keyframes' depth hold the keyframes that see them
(`pipelines.slam.planes`), where the map's up is measured (odometry at the first keyframe) or
the platform is a ground robot (`slam.planar`).
"""

from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from litevloc.base.errors import LiteVLocError
from litevloc.base.geometry import invert, make_T, so3_exp
from litevloc.base.params.localization import LocalizationParams
from litevloc.base.params.mapping import MappingParams
from litevloc.base.params.slam import SlamParams
from litevloc.pipelines.slam.frames import frame_poses
from litevloc.pipelines.slam.frontend import FrontEnd
from litevloc.pipelines.slam.graph import GraphResult, optimise
from litevloc.pipelines.slam.level import LevelFloor, floor_of
from litevloc.pipelines.slam.loops import LoopCounts, LoopSearch, loop_closures
from litevloc.pipelines.slam.odometry import OdometryTrack
from litevloc.pipelines.slam.planar import planar_edges
from litevloc.pipelines.slam.planes import WallResult, optimise_with_walls
from litevloc.pipelines.slam.types import F64, Edge, FrameRecord, FrameRef, Keyframe, LoopAttempt, SlamModels, Timings


class SlamError(LiteVLocError, ValueError):
    """The recording cannot be posed (no usable frame); the message says why."""


@dataclass
class SlamResult:
    """Keyframes, all edges (odometry, visual, loops), the optimised graph, every frame's pose
    (None where left out of the map) in the order the frames came, and the report."""

    keyframes: list[Keyframe]
    edges: list[Edge]
    graph: GraphResult
    frames: list[FrameRecord]
    frame_poses: list[F64 | None]
    T_map_first: F64
    report: dict[str, Any] = field(default_factory=dict)
    level: LevelFloor | None = None
    walls: WallResult | None = None

    @property
    def loops(self) -> list[Edge]:
        return [e for e in self.edges if e.kind == "loop"]


def up_rotation(up: tuple[float, float, float]) -> F64:
    """3x3 rotation taking +z onto the unit vector `up`."""
    u = np.asarray(up, np.float64) / np.linalg.norm(up)
    axis = np.cross([0.0, 0.0, 1.0], u)
    s, c = float(np.linalg.norm(axis)), float(u[2])
    if s < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    return so3_exp(axis / s * np.arctan2(s, c))


def map_frame(T_odom_base: F64 | None, T_base_camera: F64, up: tuple[float, float, float]) -> tuple[F64, str]:
    """T_map_camera of the first keyframe, from its odometry pose (None without) and the camera
    mount, and how gravity was found (see the module docstring)."""
    R_up = make_T(up_rotation(up), np.zeros(3))
    if T_odom_base is not None:
        T_ob = np.asarray(T_odom_base, np.float64)
        yaw = float(np.arctan2(T_ob[1, 0], T_ob[0, 0]))
        level = make_T(so3_exp(np.array([0.0, 0.0, yaw])), T_ob[:3, 3])
        return R_up @ invert(level) @ T_ob @ T_base_camera, \
            "odometry frame z (the wheel odometry's frame is level); map origin at the first keyframe's base_link"
    return R_up @ T_base_camera, ("the configured camera mount (fusion.base_camera_*) on a level robot at the first "
                                  "keyframe: no odometry there and no IMU in the recording")


class SlamSession:
    """Online front end + loop search, then `finish()` (see the module docstring)."""

    def __init__(self, params: SlamParams, mapping: MappingParams, localization: LocalizationParams,
                 models: SlamModels, T_base_camera: F64, has_odometry: bool) -> None:
        self.params, self.mapping, self.localization, self.models = params, mapping, localization, models
        self.T_base_camera = np.asarray(T_base_camera, np.float64)
        self.has_odometry = has_odometry
        self.track = OdometryTrack(params.odometry)
        self.front = FrontEnd(params, mapping, localization, models, self.T_base_camera)
        self.search = LoopSearch(params.loops)
        self.loop_edges: list[Edge] = []
        self.attempts: list[LoopAttempt] = []
        self.loop_counts = LoopCounts()
        self.timings = Timings()
        self._pending: deque[FrameRef] = deque()
        self._now = -1

    def add_odometry(self, t_ns: int, T_odom_base: F64) -> None:
        """One odometry sample of base_link (time order)."""
        self.track.add(int(t_ns), T_odom_base)
        self._now = max(self._now, int(t_ns))
        self._release(False)

    def add_frame(self, ref: FrameRef) -> None:
        """One camera frame (time order); its images are loaded only if the front end needs them."""
        self._pending.append(ref)
        self._now = max(self._now, int(ref.t_ns))
        self._release(False)

    def _release(self, final: bool) -> None:
        gap_ns = int(self.params.odometry.max_gap_s * 1e9)
        while self._pending:
            ref = self._pending[0]
            waiting = self.has_odometry and not self.track.covers_until(ref.t_ns) and self._now - ref.t_ns <= gap_ns
            if waiting and not final:
                return
            self._pending.popleft()
            self._process(ref, self.track.pose_at(ref.t_ns) if self.has_odometry else None)

    def _process(self, ref: FrameRef, odom: tuple[int, F64] | None) -> None:
        t0 = time.perf_counter()
        kf = self.front.add(ref, odom)
        t1 = time.perf_counter()
        self.timings.front_end += t1 - t0
        if kf is None:
            return
        if kf.id % self.params.loops.search_every:
            return
        self.search.add(kf.id, kf.vpr)
        pregate = self.params.loops.chain_pregate and self.params.graph.gate_loops
        edges, attempts = loop_closures(kf, self.front.keyframes, self.search, self.models.match_loop,
                                        self.localization, self.params.loops, self.loop_counts,
                                        self.params.graph if pregate else None)
        self.loop_edges.extend(edges)
        self.attempts.extend(attempts)
        self.timings.loop_search += time.perf_counter() - t1

    def finish(self) -> SlamResult:
        """Optimise and pose every frame; SlamError when no keyframe could be made."""
        self._release(True)
        kfs = self.front.keyframes
        if not kfs:
            raise SlamError("no keyframe: no frame with colour and depth reached the SLAM")
        T_first, up_note = map_frame(None if kfs[0].odom is None else kfs[0].odom[1], self.T_base_camera,
                                     self.mapping.up)
        t0 = time.perf_counter()
        edges = self.front.edges + planar_edges(kfs, self.T_base_camera, self.params.planar) + self.loop_edges
        pl = self.params.planar
        level = floor_of(T_first, self.T_base_camera, self.mapping.up, pl.sigma_height_m,
                         float(np.radians(pl.sigma_tilt_deg))) if pl.enabled and pl.level_floor else None
        graph = optimise(kfs, edges, T_first, self.params.graph, level)
        walls = None
        # a wall is told by its horizontal normal: only where the map's up is measured (the odometry's level
        # frame) or the platform is a ground robot (slam.planar), not where it is the camera mount's guess
        up_known = kfs[0].odom is not None or self.params.planar.enabled
        if self.params.planes.enabled and up_known:
            graph, walls = optimise_with_walls(kfs, {kf.id: kf.cloud for kf in kfs}, edges, graph, T_first,
                                               np.asarray(self.mapping.up, np.float64), self.params.graph,
                                               self.params.planes, level)
        poses = frame_poses(self.front.frames, graph.poses)
        self.timings.optimisation += time.perf_counter() - t0
        res = SlamResult(kfs, edges, graph, self.front.frames, poses, T_first, level=level, walls=walls)
        res.report = self._report(res, up_note)
        return res

    def no_loop_poses(self, res: SlamResult) -> dict[int, F64]:
        """The keyframe poses optimised without the loop edges (for the report's comparison)."""
        g = optimise(res.keyframes, [e for e in res.edges if e.kind != "loop"], res.T_map_first, self.params.graph,
                     res.level)
        return g.poses

    def odometry_poses(self, res: SlamResult) -> dict[int, F64] | None:
        """Keyframe camera poses from the odometry alone, in the map frame (None without odometry)."""
        first = res.keyframes[0]
        if first.odom is None:
            return None
        T_map_odom = res.T_map_first @ invert(first.odom[1] @ self.T_base_camera)
        return {kf.id: T_map_odom @ kf.odom[1] @ self.T_base_camera for kf in res.keyframes if kf.odom is not None}

    def _report(self, res: SlamResult, up_note: str) -> dict[str, Any]:
        c = self.front.counts
        loops = res.loops
        kept = [w > self.params.graph.kept_weight for w in res.graph.loop_weights]
        gate = res.graph.loop_gate or [""] * len(loops)
        rejected = [{"from_keyframe": e.a, "to_keyframe": e.b, "from_frame": res.keyframes[e.a].index,
                     "to_frame": res.keyframes[e.b].index, "weight": round(w, 3), "inliers": e.inliers,
                     "by": g or "optimiser"}
                    for e, w, k, g in zip(loops, res.graph.loop_weights, kept, gate, strict=True) if not k]
        by_gate: dict[str, int] = {}
        for g in gate:
            if g:
                by_gate[g] = by_gate.get(g, 0) + 1
        reasons: dict[str, int] = {}
        for a in self.attempts:
            if not a.accepted:
                key = a.reason.split("(")[0].split(":")[0].strip()
                reasons[key] = reasons.get(key, 0) + 1
        n_posed = sum(T is not None for T in res.frame_poses)
        odo = "none (visual odometry only)" if not self.has_odometry else (
            "/odom (wheel odometry) and visual edges" if c["keyframes_with_odometry"] == len(res.keyframes)
            else f"/odom for {c['keyframes_with_odometry']} of {len(res.keyframes)} keyframes, visual odometry "
                 "for the rest")
        faults = [f.as_dict() for f in (self.track.faults + self.front.faults)]
        rep: dict[str, Any] = {
            "odometry_source": odo, "up": up_note, "imu": "none in the recording",
            "frames": len(res.frames), "frames_posed": n_posed, "frames_left_out": len(res.frames) - n_posed,
            "keyframes": len(res.keyframes), "keyframes_in_map": len(res.graph.poses),
            "keyframes_left_out": len(res.graph.dropped), "chains": c["chains"],
            "frames_tracked": c["frames_tracked"], "tracking_failures": c["tracking_failures"],
            "edges": {"odometry": c["odometry_edges"], "visual": c["visual_edges"],
                      "odometry_dropped": c["odometry_edges_dropped"], "visual_dropped": c["visual_edges_dropped"],
                      "visual_failed": c["visual_edge_failures"],
                      "planar": sum(e.kind == "planar" for e in res.edges)},
            "loops": {"candidates": self.loop_counts.candidates, "skipped_by_chain_pregate": self.loop_counts.pregated,
                      "tried": self.loop_counts.tried,
                      "verified": self.loop_counts.verified, "kept": int(sum(kept)),
                      "rejected_by_gate": by_gate, "rejected_by_optimiser": len(rejected) - sum(by_gate.values()),
                      "rejected": rejected,
                      "verification_failures": dict(sorted(reasons.items(), key=lambda kv: -kv[1]))},
            "odometry": {"samples": self.track.samples, "segments": self.track.segments,
                         "out_of_order": self.track.out_of_order},
            "faults": faults,
            "walls": res.walls.as_dict() if res.walls is not None else (
                "off: the map's up is the camera mount's guess (no odometry at the first keyframe, slam.planar off)"
                if self.params.planes.enabled else "off (slam.planes.enabled)"),
            "seconds": {"front_end": round(self.timings.front_end, 2),
                        "loop_search": round(self.timings.loop_search, 2),
                        "optimisation": round(self.timings.optimisation, 2)},
        }
        rep["warnings"] = _warnings(rep, self.has_odometry)
        return rep


def _warnings(rep: dict[str, Any], has_odometry: bool) -> list[str]:
    """What a user should know about this pass, in words."""
    out = []
    if rep["loops"]["kept"] == 0:
        out.append("no loop closed: the map is only as good as the odometry and visual edges (it drifts); drive "
                   "back through places already mapped, facing the way you first saw them, and rebuild")
    if not has_odometry:
        out.append("no odometry in the recording: keyframes come from visual odometry alone (record the robot's "
                   "/odom too where you can: it bridges views the camera cannot track)")
    if rep["keyframes_left_out"]:
        out.append(f"{rep['keyframes_left_out']} keyframe(s) left out: their stretch is joined to the map by no "
                   "odometry, visual edge or kept loop (see faults)")
    return out
