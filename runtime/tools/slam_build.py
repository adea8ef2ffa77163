"""The shell of `litevloc map build --poses slam`: feeds a recording, dataset or simulated pass
to the SLAM (`pipelines.slam.SlamSession`) in one pass, builds the map from its poses with the
keyframes' features already computed, and evaluates against the ground truth afterwards.

Ground truth is never given to the SLAM: the stream's `GroundTruthPose` messages are set
aside (`SlamPass.ground_truth`) and read only by `evaluate_against`, after the map is built.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from litevloc.base.params.slam import SlamParams
from litevloc.config.schema import LiteVLocConfig
from litevloc.hw.messages import EncodedRgbdFrame, GroundTruthPose, Odometry, RgbdFrame, SourceMessage
from litevloc.pipelines.slam.evaluate import evaluate
from litevloc.pipelines.slam.graph import GraphResult, optimise
from litevloc.pipelines.slam.level import LevelFloor
from litevloc.pipelines.slam.planes import WallFactors, resolve_with_walls
from litevloc.pipelines.slam.session import SlamResult, SlamSession
from litevloc.pipelines.slam.types import F64, Edge, EdgeKind, FrameImages, FrameRef, SlamModels
from litevloc.pipelines.topomap.build import MapBuilder
from litevloc.runtime.vloc_models import ModelBundle


def slam_models(cfg: LiteVLocConfig, bundle: ModelBundle) -> SlamModels:
    """The SLAM's callables: `bundle`'s extractor, place recognizer and matcher (the localizer's,
    for loops) plus the configured cheap matcher for visual edges (`slam.vo_matcher`)."""
    from litevloc.models.registry import load_matcher

    vo = dataclasses.replace(bundle, matcher=load_matcher(cfg.slam.vo_matcher, cfg.models))
    return SlamModels(bundle.extract, bundle.describe, vo.match, bundle.match)


def new_session(cfg: LiteVLocConfig, models: SlamModels, has_odometry: bool) -> SlamSession:
    return SlamSession(cfg.slam, cfg.mapping, cfg.localization, models, cfg.fusion.T_base_camera(), has_odometry)


@dataclass
class SlamPass:
    """What one pass over the source gave: the SLAM result, frames skipped before the SLAM
    (no depth), and the ground truth set aside for the evaluation (t_ns -> T_world_camera)."""

    result: SlamResult
    skipped: dict[str, int] = field(default_factory=dict)
    ground_truth: dict[int, F64] = field(default_factory=dict)


def _decoded(frame: EncodedRgbdFrame) -> FrameImages:
    """The images of a frame whose colour is decoded only now (StreamError naming it if it does not decode)."""
    f = frame.decode()
    assert f.depth is not None  # frames without depth are skipped before the SLAM
    return FrameImages(f.color, f.depth, f.color_jpeg)


def run_on_messages(session: SlamSession, messages: Iterable[SourceMessage],
                    on_frame: Callable[[], None] | None = None) -> SlamPass:
    """Feed a time-ordered message stream to the SLAM; ground truth only set aside. Frames
    may come with their colour undecoded (`EncodedRgbdFrame`): only those the front end
    loads are decoded."""
    skipped: dict[str, int] = {}
    gt: dict[int, F64] = {}
    for m in messages:
        if isinstance(m, Odometry):
            session.add_odometry(m.t_ns, m.T_odom_base)
        elif isinstance(m, RgbdFrame | EncodedRgbdFrame):
            if on_frame is not None:
                on_frame()
            if m.depth is None:
                skipped["frame without depth"] = skipped.get("frame without depth", 0) + 1
                continue
            load = functools.partial(_decoded, m) if isinstance(m, EncodedRgbdFrame) else \
                functools.partial(FrameImages, m.color, m.depth, m.color_jpeg)
            session.add_frame(FrameRef(m.t_ns, m.index, m.K, load))
        elif isinstance(m, GroundTruthPose):
            gt[m.t_ns] = m.T_world_camera
    return SlamPass(session.finish(), skipped, gt)


def run_on_sim(session: SlamSession, src: Any, on_frame: Callable[[], None] | None = None) -> SlamPass:
    """Feed a simulated pass (`sim.source.SimSequenceSource`): its drifting odometry and its
    frames, rendered only when the SLAM asks for them. No ground truth is read here."""
    odo_t, odo_T = src.run.t_ns, src.run.T_odom_base
    K = src.params.intrinsics.K

    def images(i: int) -> FrameImages:
        f = src.frame(i)
        return FrameImages(f.color, f.depth, None)

    k = 0
    for i, t in enumerate(src.frame_times):
        while k < len(odo_t) and odo_t[k] <= t:
            session.add_odometry(int(odo_t[k]), odo_T[k])
            k += 1
        session.add_frame(FrameRef(int(t), i, K, functools.partial(images, i)))
        if on_frame is not None:
            on_frame()
    for j in range(k, len(odo_t)):
        session.add_odometry(int(odo_t[j]), odo_T[j])
    return SlamPass(session.finish())


def feed_builder(res: SlamResult, builder: MapBuilder) -> int:
    """Both passes of the map builder from the SLAM result: every posed frame (keyframes with
    their depth points, the others as trajectory), then the selected keyframes' features as
    the SLAM computed them. Returns the number of frames without a pose."""
    by_index = {kf.index: kf for kf in res.keyframes}
    unposed = 0
    for rec, T in zip(res.frames, res.frame_poses, strict=True):
        if T is None:
            unposed += 1
            continue
        kf = by_index.get(rec.index) if rec.keyframe is not None else None
        if kf is None:
            builder.add_pose(T, rec.index)
        else:
            builder.add_points(rec.t_ns, kf.cloud.astype(np.float64), kf.size, kf.K, T, rec.index)
    for pos in builder.select():
        kf = by_index[builder.candidates[pos].index]
        builder.attach_features(pos, kf.features, kf.features.depth, kf.vpr, kf.jpeg, kf.size)
    return unposed


def evaluate_against(session: SlamSession, res: SlamResult, gt_by_stamp: dict[int, F64]) -> dict[str, Any]:
    """The report's error block against the ground truth (camera poses by frame stamp)."""
    ref = {kf.id: gt_by_stamp[kf.t_ns] for kf in res.keyframes if kf.t_ns in gt_by_stamp}
    if len(ref) < 3:
        return {"reference": "none (fewer than 3 keyframes have a ground-truth pose)"}
    out = evaluate(res.graph.poses, ref, res.loops, res.graph.loop_weights, session.params.graph.kept_weight,
                   session.odometry_poses(res), session.no_loop_poses(res))
    out["reference"] = "the source's ground truth, read after the build"
    return out


_KINDS: tuple[EdgeKind, ...] = ("odometry", "visual", "loop", "planar")


@dataclass(frozen=True, eq=False)
class SavedKeyframe:
    """A keyframe as `save_graph` keeps it (what the optimiser and an evaluation need)."""

    id: int
    chain: int
    T_init: F64
    index: int
    t_ns: int


@dataclass
class SavedGraph:
    """A SLAM pose graph read back by `load_graph`; `poses` (N, 4, 4) optimised T_map_camera,
    NaN for keyframes left out of the map."""

    keyframes: list[SavedKeyframe]
    edges: list[Edge]
    loop_weights: list[float]
    poses: F64
    T_map_first: F64
    level: LevelFloor | None = None
    walls: WallFactors | None = None


def solve_saved(g: SavedGraph, params: SlamParams, extra: Sequence[Edge] = ()) -> GraphResult:
    """A saved graph optimised as the build did (loops decided by GNC, then the build's wall
    factors), with `extra` edges added (the saved poses again when there are none)."""
    edges = g.edges + list(extra)
    res = optimise(g.keyframes, edges, g.T_map_first, params.graph, g.level)
    if g.walls is None:
        return res
    return resolve_with_walls(g.keyframes, edges, res, g.T_map_first, params.graph, params.planes, g.walls, g.level)


def save_graph(path: Path, res: SlamResult) -> None:
    """The SLAM's keyframes and edges as a .npz (no pickle), for analyses that re-optimise it."""
    n = len(res.keyframes)
    poses = np.full((n, 4, 4), np.nan)
    for k, T in res.graph.poses.items():
        poses[k] = T
    E = res.edges
    path.parent.mkdir(parents=True, exist_ok=True)
    lv = res.level
    extra: dict[str, Any] = {} if lv is None else {"level_up": lv.up, "level_T_base_camera": lv.T_base_camera,
                                   "level_sigmas": np.array([lv.height_m, lv.sigma_height_m, lv.sigma_tilt_rad])}
    if res.walls is not None:
        extra.update(wall_observations=res.walls.factors.observations, wall_planes=res.walls.factors.walls)
    np.savez(path, **extra, kf_id=np.array([k.id for k in res.keyframes], np.int64),
             kf_chain=np.array([k.chain for k in res.keyframes], np.int64),
             kf_T_init=np.stack([k.T_init for k in res.keyframes]), kf_index=np.array([k.index for k in res.keyframes]),
             kf_t_ns=np.array([k.t_ns for k in res.keyframes], np.int64), kf_pose=poses,
             edge_a=np.array([e.a for e in E], np.int64), edge_b=np.array([e.b for e in E], np.int64),
             edge_kind=np.array([_KINDS.index(e.kind) for e in E], np.int64),
             edge_T=np.stack([e.T_a_b for e in E]).reshape(-1, 4, 4), edge_cov=np.stack([e.covariance for e in E]
                                                                                         ).reshape(-1, 6, 6),
             edge_inliers=np.array([e.inliers for e in E], np.int64),
             loop_weights=np.array(res.graph.loop_weights, np.float64), T_map_first=res.T_map_first)


def load_graph(path: Path) -> SavedGraph:
    """Read `save_graph`'s file."""
    with np.load(path, allow_pickle=False) as z:
        kfs = [SavedKeyframe(int(i), int(c), T, int(x), int(t)) for i, c, T, x, t in
               zip(z["kf_id"], z["kf_chain"], z["kf_T_init"], z["kf_index"], z["kf_t_ns"], strict=True)]
        edges = [Edge(int(a), int(b), T, C, _KINDS[int(k)], int(n)) for a, b, k, T, C, n in
                 zip(z["edge_a"], z["edge_b"], z["edge_kind"], z["edge_T"], z["edge_cov"], z["edge_inliers"],
                     strict=True)]
        level = None
        if "level_up" in z:
            h, s_h, s_t = (float(x) for x in z["level_sigmas"])
            level = LevelFloor(np.asarray(z["level_up"]), np.asarray(z["level_T_base_camera"]), h, s_h, s_t)
        walls = WallFactors(np.asarray(z["wall_observations"]), np.asarray(z["wall_planes"])) \
            if "wall_observations" in z else None
        return SavedGraph(kfs, edges, [float(w) for w in z["loop_weights"]], np.asarray(z["kf_pose"]),
                          np.asarray(z["T_map_first"]), level, walls)
