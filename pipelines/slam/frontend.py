"""The SLAM front end: keyframes and the edges between nearby ones, one frame at a time.

* Keyframes are spaced by the mapping pre-filter's thresholds (`mapping.keyframes`:
  translation or rotation since the last keyframe) times `slam.keyframe_step_scale` (the
  rotation step also times `slam.keyframe_rotation_scale`), measured with the odometry where
  the frame and the last keyframe lie in one odometry segment; no image is touched for other
  frames.
* Where the odometry cannot say (no odometry in the recording, a gap, a jump), every
  `visual.track_every`-th frame is tracked against the last keyframe (features, the cheap
  matcher, PnP with the frame's depth); it becomes a keyframe when it moved enough, when its
  inliers run low, or when tracking fails (then it starts a new chain unless the odometry links it).
* A new keyframe gets an odometry edge from the previous one (same odometry segment) and
  visual edges (PnP with its depth) from up to `visual.neighbours` previous ones. Where the
  odometry or tracking predicts the motion, matches come from projecting the keyframe's points
  with that prediction (mutual nearest neighbours over all keypoints, within a radius: ~1 ms,
  and repeated textures cannot pair with the wrong repetition); the cheap matcher runs only
  where too few are found and no odometry predicts the motion (`visual.guided_only`: the
  matcher pairs a repeating texture with the wrong repetition, and the edge then outvotes the
  odometry). Of these edges the set whose estimates of the new keyframe's pose agree (within
  `visual.max_disagreement_sigma` of their noise) with the most independent votes is kept:
  the odometry is one vote and the visual edges together one (they all use the new
  keyframe's image, so one aliased image shifts them alike); a tie keeps the odometry, and
  with `visual.skip_edge_ties` the next keyframe's skip edge breaks it
  (`pipelines.slam.disputes`: a slipping wheel is corrected, one aliased image is not
  followed, a texture repeating along the path can fool it); both outcomes are faults.

Camera motion from odometry: `T_odom_camera = T_odom_base @ T_base_camera`.
"""

from __future__ import annotations

import dataclasses
import itertools
from dataclasses import dataclass

import numpy as np

from litevloc.base.geometry import backproject_pixels, invert, rotation_angle
from litevloc.base.params.localization import LocalizationParams, RefineParams
from litevloc.base.params.mapping import KeyframeParams, MappingParams
from litevloc.base.params.slam import SlamParams
from litevloc.pipelines.depth_lookup import depth_at
from litevloc.pipelines.guided_matching import match_by_projection
from litevloc.pipelines.keypoint_alignment import AlignmentView, align_keypoints, alignment_view
from litevloc.pipelines.localization.refine import KeyframeObservations, refine_pose
from litevloc.pipelines.pnp import solve_pnp
from litevloc.pipelines.slam.disputes import ODOMETRY_DROPPED, Dispute, dispute_faults, vision_wins
from litevloc.pipelines.slam.odometry import odometry_edge
from litevloc.pipelines.slam.types import F64, Edge, Fault, FrameImages, FrameRecord, FrameRef, Keyframe, SlamModels
from litevloc.pipelines.topomap.build import candidate_points, encode_jpeg
from litevloc.pipelines.topomap.keyframes import moved
from litevloc.pipelines.topomap.types import NodeFeatures

_RT = [3, 4, 5, 0, 1, 2]  # (t, rotvec) -> GTSAM's (rotvec, t)


@dataclass(frozen=True, eq=False)
class Relative:
    """A frame's pose relative to a keyframe: T_keyframe_frame (4x4), its 6x6 covariance in
    GTSAM's order (see `pipelines.slam.types`) and the inliers supporting it."""

    T: F64
    covariance: F64
    inliers: int


def edge_refine_params(loc: RefineParams, floor_m: float, floor_deg: float, keyframes: int | None = None
                       ) -> RefineParams:
    """The localizer's joint refinement as the SLAM's edges use it: its noise model and gates,
    without its systematic terms (fitted for live queries against a map, they make an edge
    between two keyframes of one pass 20x less certain than its error: measured on a simulated
    pass), with the edge's noise floor; `keyframes`: how many keyframes must agree (None: as
    the localizer)."""
    r = dataclasses.replace(loc, sigma_sys_t_m=0.0, sigma_sys_r_deg=0.0, sigma_sys_t_per_rad=0.0,
                            sigma_sys_r_per_rad=0.0, sigma_sys_t_per_m=0.0, sigma_sys_r_deg_per_m=0.0,
                            min_sigma_t_m=floor_m, min_sigma_r_deg=floor_deg)
    return r if keyframes is None else dataclasses.replace(r, min_keyframes=keyframes, max_keyframes=keyframes)


def keyframe_spacing(params: SlamParams, mapping: MappingParams) -> KeyframeParams:
    """The motion steps that make a keyframe: `mapping.keyframes`' times `slam.keyframe_step_scale`,
    the rotation step also times `slam.keyframe_rotation_scale`."""
    kp, k = mapping.keyframes, params.keyframe_step_scale
    k_rot = k * params.keyframe_rotation_scale
    return dataclasses.replace(kp, min_translation_m=k * kp.min_translation_m,
                               min_rotation_deg=k_rot * kp.min_rotation_deg)


def edge_error(T_a_b: F64, T_a_b_other: F64) -> tuple[float, float]:
    """Translation (m) and rotation (rad) of inv(T_a_b) @ T_a_b_other: how far two measurements
    of the same motion disagree."""
    E = invert(T_a_b) @ T_a_b_other
    return float(np.linalg.norm(E[:3, 3])), rotation_angle(E[:3, :3])


class FrontEnd:
    """Keyframes and their odometry and visual edges (see the module docstring)."""

    def __init__(self, params: SlamParams, mapping: MappingParams, localization: LocalizationParams,
                 models: SlamModels, T_base_camera: F64) -> None:
        self.params, self.mapping, self.models = params, mapping, models
        self._spacing = keyframe_spacing(params, mapping)
        vp = params.visual.pnp
        self._refine = edge_refine_params(localization.refine, vp.min_sigma_trans_m,
                                          float(np.degrees(vp.min_sigma_rot_rad)), keyframes=1)
        self.T_base_camera = np.asarray(T_base_camera, np.float64)
        self.keyframes: list[Keyframe] = []
        self.edges: list[Edge] = []
        self.frames: list[FrameRecord] = []
        self.disputes: list[Dispute] = []
        self._faults: list[Fault] = []
        self.counts = {"frames": 0, "frames_tracked": 0, "tracking_failures": 0, "odometry_edges": 0,
                       "odometry_edges_dropped": 0, "visual_edges": 0, "visual_edges_dropped": 0,
                       "visual_edge_failures": 0, "chains": 0, "keyframes_with_odometry": 0}
        self._since_track = 0

    @property
    def faults(self) -> list[Fault]:
        """What the front end worked around, in time order (unlinked keyframes, disputed ones)."""
        return sorted(self._faults + dispute_faults(self.disputes), key=lambda f: f.t_s)

    # ---------------------------------------------------------------- per frame
    def add(self, ref: FrameRef, odom: tuple[int, F64] | None) -> Keyframe | None:
        """Process one frame (time order) with its odometry pose (segment, T_odom_base) or None;
        returns the keyframe it became, if it did."""
        self.counts["frames"] += 1
        rec = FrameRecord(ref.index, ref.t_ns)
        self.frames.append(rec)
        if not self.keyframes:
            return self._keyframe(ref, rec, ref.load(), odom, None)
        last = self.keyframes[-1]
        if odom is not None and last.odom is not None and odom[0] == last.odom[0]:
            T_rel = invert(last.odom[1] @ self.T_base_camera) @ odom[1] @ self.T_base_camera
            rec.anchor, rec.T_anchor_frame, rec.how = last.id, T_rel, "odometry"
            self._since_track = self.params.visual.track_every - 1  # the first frame without odometry is tracked
            if not moved(np.eye(4), T_rel, self._spacing):
                return None
            return self._keyframe(ref, rec, ref.load(), odom, None)
        self._since_track += 1
        if self._since_track < self.params.visual.track_every:
            return None
        self._since_track = 0
        images = ref.load()
        feats, points = self._features(images, ref.K)
        view = self._view(images, ref.K)
        self.counts["frames_tracked"] += 1
        res = self._relative(points, feats, last, view=view)
        if res is None:
            self.counts["tracking_failures"] += 1
            return self._keyframe(ref, rec, images, odom, (feats, points, view))
        rec.anchor, rec.T_anchor_frame, rec.how = last.id, res.T, "visual"
        if moved(np.eye(4), res.T, self._spacing) or res.inliers < self.params.visual.track_min_inliers:
            return self._keyframe(ref, rec, images, odom, (feats, points, view), tracked=res)
        return None

    # ---------------------------------------------------------------- building blocks
    def _features(self, images: FrameImages, K: F64) -> tuple[NodeFeatures, F64]:
        """Local features with the depth at each keypoint, and the keypoints lifted (NaN rows
        without depth), camera frame."""
        f = self.models.extract(images.color)
        kp = np.asarray(f.keypoints, np.float32)
        z = depth_at(images.depth, kp, self.mapping.depth)
        h, w = images.color.shape[:2]
        feats = NodeFeatures(kp, np.asarray(f.descriptors), np.asarray(f.scores, np.float32), (w, h), z)
        pts = np.full((len(kp), 3), np.nan)
        ok = np.isfinite(z)
        pts[ok] = backproject_pixels(K, kp[ok].astype(np.float64), z[ok].astype(np.float64))
        return feats, pts

    def _view(self, images: FrameImages, K: F64) -> AlignmentView | None:
        """A frame's images for keypoint alignment (None when `slam.visual.align` is off)."""
        return alignment_view(images.color, images.depth, K) if self.params.visual.align.enabled else None

    def _relative(self, points: F64, feats: NodeFeatures, target: Keyframe, prior: F64 | None = None,
                  guided_only: bool = False, view: AlignmentView | None = None) -> Relative | None:
        """Pose of a frame relative to `target` (T_target_frame, see `Relative`) from its lifted
        points: matches (by projection with a predicted `prior`, else the cheap matcher; never the
        matcher when `guided_only`), PnP into the target's image, the target's keypoints moved
        onto the frame's surface points where both have a `view` (`pipelines.keypoint_alignment`),
        then the joint refinement with both images' depth (3D residuals pin the motion along the
        optical axis that reprojections leave loose). None when a gate fails."""
        vp = self.params.visual
        i_s = i_t = np.zeros(0, np.int64)
        if prior is not None:
            i_s, i_t = match_by_projection(points, feats.descriptors, prior, target.features.keypoints,
                                           target.features.descriptors, target.K, np.eye(4), vp.guided_radius_px,
                                           vp.guided_min_similarity, True)
        if len(i_s) < vp.pnp.min_inliers:
            if prior is not None and guided_only:
                return None
            i_s, i_t = self.models.match_vo(feats, target.features)
        pts = points[i_s]
        ok = np.all(np.isfinite(pts), axis=1)
        if ok.sum() < vp.pnp.min_inliers:
            return None
        kps = np.asarray(target.features.keypoints, np.float64)[i_t[ok]]
        res = solve_pnp(pts[ok], kps, target.K, vp.pnp)
        if not res.accepted or res.T_target_source is None:
            return None
        z = None if target.features.depth is None else np.asarray(target.features.depth, np.float64)[i_t[ok]]
        if view is not None and target.view is not None:
            uv_s = np.asarray(feats.keypoints, np.float64)[i_s[ok]]
            kps, moved_ = align_keypoints(view, target.view, uv_s, pts[ok], kps, res.T_target_source, vp.align)
            if z is not None and moved_.any():
                z[moved_] = depth_at(target.view.depth, kps[moved_], self.mapping.depth)
        obs = KeyframeObservations(target.id, pts[ok], kps, target.K, np.eye(4), z)
        joint = refine_pose(res.T_target_source, [obs], self._refine)
        if not joint.accepted or joint.covariance is None:
            return None
        return Relative(joint.T_map_camera, joint.covariance[np.ix_(_RT, _RT)], joint.n_inliers)

    def _keyframe(self, ref: FrameRef, rec: FrameRecord, images: FrameImages, odom: tuple[int, F64] | None,
                  computed: tuple[NodeFeatures, F64, AlignmentView | None] | None,
                  tracked: Relative | None = None) -> Keyframe:
        """A new keyframe from a frame (`computed`: its features, lifted points and alignment view
        where tracking made them already), its edges to the previous keyframes, and its place."""
        feats, points, view = computed if computed is not None else (*self._features(images, ref.K),
                                                                     self._view(images, ref.K))
        h, w = images.color.shape[:2]
        kf = Keyframe(
            id=len(self.keyframes), index=ref.index, t_ns=ref.t_ns, K=np.asarray(ref.K, np.float64), size=(w, h),
            features=feats, points=points, vpr=np.asarray(self.models.describe(images.color), np.float32),
            jpeg=images.jpeg or encode_jpeg(images.color, self.mapping.jpeg_quality, f"frame {ref.index}"),
            cloud=candidate_points(images.depth, ref.K, self.mapping.keyframes).astype(np.float32),
            odom=odom, T_init=np.eye(4), chain=0, view=view)
        if odom is not None:
            self.counts["keyframes_with_odometry"] += 1
        rec.keyframe = kf.id
        new_edges = self._edges_to_previous(kf, tracked)
        self._place(kf, new_edges)
        self._advance_path(kf, new_edges)
        self.keyframes.append(kf)
        self.edges.extend(new_edges)
        keep = max(self.params.visual.neighbours, 2)  # visual edges and the skip edge reach this far back
        if len(self.keyframes) > keep:
            self.keyframes[-keep - 1].view = None  # its images are not needed again (memory)
        return kf

    def _edges_to_previous(self, kf: Keyframe, tracked: Relative | None) -> list[Edge]:
        """Odometry and visual edges from the previous keyframes to `kf`, the agreeing set with most votes."""
        if not self.keyframes:
            return []
        prev = self.keyframes[-1]
        odo: Edge | None = None
        if kf.odom is not None and prev.odom is not None and kf.odom[0] == prev.odom[0]:
            T, cov = odometry_edge(prev.odom[1], kf.odom[1], self.T_base_camera, self.params.odometry)
            odo = Edge(prev.id, kf.id, T, cov, "odometry")
        predicted = odo.T_a_b if odo is not None else (None if tracked is None else tracked.T)
        vp = self.params.visual
        visual: list[Edge] = []
        for other in reversed(self.keyframes[-self.params.visual.neighbours:]):
            prior = None if predicted is None else invert(other.T_init) @ prev.T_init @ predicted
            res = tracked if (other is prev and tracked is not None) else \
                self._relative(kf.points, kf.features, other, prior, odo is not None and vp.guided_only, kf.view)
            if res is None:
                self.counts["visual_edge_failures"] += 1
                continue
            visual.append(Edge(other.id, kf.id, res.T, res.covariance, "visual", inliers=res.inliers))
        open_dispute = self.disputes[-1] if self.disputes and self.disputes[-1].keyframe == prev.id else None
        if odo is not None and open_dispute is not None and vp.skip_edge_ties:
            self._settle(open_dispute, kf, odo, visual)
        kept = self._consensus(([odo] if odo is not None else []) + visual)
        if odo is not None and odo not in kept:
            self.counts["odometry_edges_dropped"] += 1
        if odo is not None and len(visual) >= 2 and not any(e in kept for e in visual):
            self.disputes.append(Dispute(kf.id, kf.t_ns * 1e-9, odo, self._consensus(visual), len(visual)))
        self.counts["visual_edges_dropped"] += sum(e not in kept for e in visual)
        self.counts["odometry_edges"] += int(odo is not None and odo in kept)
        self.counts["visual_edges"] += sum(e in kept for e in visual)
        return kept

    def _settle(self, d: Dispute, kf: Keyframe, odo: Edge, visual: list[Edge]) -> None:
        """Break the tie at the previous keyframe with the skip edge into `kf` from the one before
        it (`pipelines.slam.disputes`); `odo` and `visual`: `kf`'s edges (the skip edge, computed
        here with vision's prediction when the odometry's found too few matches, joins them).
        Where vision wins, the previous keyframe gets its visual edges and pose from them."""
        if len(self.keyframes) < 2 or self.keyframes[-2].id != d.odometry.a or not d.visual:
            return
        before, k = self.keyframes[-2], self.keyframes[-1]
        T_vision = self.keyframes[d.visual[0].a].T_init @ d.visual[0].T_a_b
        visual_next = next((e for e in visual if e.a == k.id), None)
        skip = next((e for e in visual if e.a == before.id), None)
        if skip is None:
            step = odo.T_a_b if visual_next is None else visual_next.T_a_b
            res = self._relative(kf.points, kf.features, before, invert(before.T_init) @ T_vision @ step, True,
                                 kf.view)
            if res is None:
                return
            skip = Edge(before.id, kf.id, res.T, res.covariance, "visual", inliers=res.inliers)
            visual.append(skip)
        if not vision_wins(d, before.T_init, k.T_init, T_vision, skip, odo, visual_next,
                           self.params.visual.max_disagreement_sigma):
            return
        d.outcome = ODOMETRY_DROPPED
        self.edges.remove(d.odometry)
        self.edges.extend(d.visual)
        self.counts["odometry_edges"] -= 1
        self.counts["odometry_edges_dropped"] += 1
        self.counts["visual_edges"] += len(d.visual)
        self.counts["visual_edges_dropped"] -= len(d.visual)
        k.T_init = T_vision
        k.path_m = before.path_m + float(np.linalg.norm(T_vision[:3, 3] - before.T_init[:3, 3]))

    def _consensus(self, edges: list[Edge]) -> list[Edge]:
        """The set of edges whose estimates of the new keyframe's pose agree pairwise with the
        most independent votes: the odometry is one vote, all visual edges together are one
        (they share the new keyframe's image: a repeating texture shifts them alike). Ties go
        to the set with the odometry, then to the larger set, then to priority order
        (odometry, then visual from the nearest keyframe back)."""
        est = [self.keyframes[e.a].T_init @ e.T_a_b for e in edges]
        k = self.params.visual.max_disagreement_sigma
        n = len(edges)
        ok = np.ones((n, n), bool)
        for i in range(n):
            for j in range(i + 1, n):
                et, er = edge_error(est[i], est[j])
                var = np.diag(edges[i].covariance) + np.diag(edges[j].covariance)
                ok[i, j] = ok[j, i] = et <= k * np.sqrt(var[3:].max()) and er <= k * np.sqrt(var[:3].max())
        best: tuple[int, ...] = ()
        best_score = (0, False, 0)
        for size in range(n, 0, -1):
            for subset in itertools.combinations(range(n), size):
                if not all(ok[i, j] for i, j in itertools.combinations(subset, 2)):
                    continue
                odometry = any(edges[i].kind == "odometry" for i in subset)
                visual = any(edges[i].kind != "odometry" for i in subset)
                score = (int(odometry) + int(visual), odometry, size)
                if score > best_score:
                    best, best_score = subset, score
        return [edges[i] for i in best]

    def _advance_path(self, kf: Keyframe, edges: list[Edge]) -> None:
        """`path_m` and `path_var_t` of a placed keyframe from the previous one of its chain."""
        prev = self.keyframes[-1] if self.keyframes else None
        if prev is None or prev.chain != kf.chain or not edges:
            return
        kf.path_m = prev.path_m + float(np.linalg.norm(kf.T_init[:3, 3] - prev.T_init[:3, 3]))
        kf.path_var_t = prev.path_var_t + min(float(np.diag(e.covariance)[3:].max()) for e in edges)

    def _place(self, kf: Keyframe, edges: list[Edge]) -> None:
        """Initial pose and chain of a new keyframe from its edges (the visual edge to the
        nearest previous keyframe first, then odometry); a keyframe no edge reaches starts a
        new chain where the previous keyframe was."""
        if not self.keyframes:
            self.counts["chains"] = 1
            return
        by_kind = sorted(edges, key=lambda e: (e.kind != "visual", -e.a))
        if by_kind:
            e = by_kind[0]
            kf.T_init = self.keyframes[e.a].T_init @ e.T_a_b
            kf.chain = self.keyframes[e.a].chain
            return
        prev = self.keyframes[-1]
        kf.T_init = prev.T_init.copy()
        kf.chain = self.counts["chains"]
        self.counts["chains"] += 1
        self._faults.append(Fault("keyframe not linked", kf.t_ns * 1e-9,
                                 f"keyframe {kf.id} (frame {kf.index}): no odometry and no visual edge reaches the "
                                 "previous keyframes", "starts a new chain; kept only if a loop joins it to the map"))
