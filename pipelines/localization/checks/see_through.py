"""The see-through check (second look): does a live pose see through the map?

Under a right pose, a keyframe's points (its stored keypoints lifted with the map's depth) that
fall in the live image lie on the live depth surface, or behind it where something occludes
them. A point the pose puts clearly *in front of* that surface would be seen where the live
camera sees farther: free space through a mapped surface. A pose verified on one repeated or
thin structure (leaflets on two shelves) puts many of the keyframes' other points there.
Across a wide view change a right pose can miss by 10-20 cm along the view and see through
too: a pose that does is moved onto the live depth (`depth_align`) and accepted where the move
is small (`see_through.align_m`, `see_through.align_deg`) and the moved pose keeps under half
the see-through limit; its covariance grows by the move.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from litevloc.base.geometry import backproject_pixels, pixels_in_view
from litevloc.base.params.localization import LocalizationParams
from litevloc.pipelines.localization.depth_align import align_to_live_depth
from litevloc.pipelines.localization.refusals import QueryRefusal, refusal_text
from litevloc.pipelines.localization.results import LocalizationResult, refused
from litevloc.pipelines.topomap.types import TopoMap

MIN_CHECKED_POINTS = 20  # map points in view with live depth, below which the see-through check cannot tell
# How far in front of the live surface a point must lie to count (fixed from the depth noise of
# structured-light and stereo cameras at room range, not tuned): 5 cm, or 5 % of the live depth.
IN_FRONT_M = 0.05
IN_FRONT_REL = 0.05


def keyframe_points(topomap: TopoMap, nodes: list[int]) -> NDArray[np.float64]:
    """(N, 3) map-frame points of `nodes`' stored keypoints that have map depth (metres); (0, 3)
    where the map has no keypoint depth."""
    out = [np.zeros((0, 3))]
    for k in nodes:
        z = topomap.keypoint_depth(k)
        if z is None:
            continue
        ok = np.isfinite(z) & (z > 0)
        kp = np.asarray(topomap.features[k].keypoints, np.float64).reshape(-1, 2)[ok]
        P = backproject_pixels(topomap.K[k], kp, np.asarray(z, np.float64)[ok])
        T = topomap.T_map_camera[k]
        out.append(P @ T[:3, :3].T + T[:3, 3])
    return np.concatenate(out)


def see_through(points_map: NDArray[np.float64], T_map_live: NDArray[np.float64], K: NDArray[np.float64],
                depth: NDArray[np.floating]) -> tuple[int, float]:
    """(n, share): of the (N, 3) map points that project into the live image (intrinsics `K`,
    depth image `depth` in metres, NaN or <= 0 = none) where it has depth, how many (n) and which
    share lie in front of the live surface by more than `IN_FRONT_M` / `IN_FRONT_REL`."""
    P, col, row = pixels_in_view(np.linalg.inv(np.asarray(T_map_live, np.float64)), points_map, K, depth.shape)
    z_live = np.asarray(depth, np.float64)[row, col]
    z_map = P[:, 2]
    valid = np.isfinite(z_live) & (z_live > 0)
    z_live, z_map = z_live[valid], z_map[valid]
    if len(z_map) == 0:
        return 0, 0.0
    in_front = z_map < z_live - np.maximum(IN_FRONT_M, IN_FRONT_REL * z_live)
    return len(z_map), float(in_front.mean())


def sees_through_reason(points_map: NDArray[np.float64], T_map_live: NDArray[np.float64], K: NDArray[np.float64],
                        depth: NDArray[np.floating], limit: float) -> str:
    """'' when at most `limit` of the (N, 3) map points the pose puts in the live depth's view lie
    in front of the live surface (see `see_through`), else the refusal reason; a pose it cannot
    check is refused; `limit` >= 1 checks nothing."""
    if limit >= 1.0:
        return ""
    n, share = see_through(points_map, T_map_live, K, depth)
    if n < MIN_CHECKED_POINTS:
        return (f"the pose puts {n} of its keyframes' map points in the live depth's view "
                f"(< {MIN_CHECKED_POINTS}): cannot check it against the live depth")
    if share > limit:
        return (f"the pose sees through the map: {share:.0%} of {n} keyframe points in view lie in front of "
                f"the live depth (> {limit:.0%})")
    return ""


def moved_onto_live_depth(res: LocalizationResult, points_map: NDArray[np.float64], K: NDArray[np.float64],
                          depth: NDArray[np.floating], p: LocalizationParams) -> LocalizationResult | None:
    """`res` with its pose moved onto the live depth (`align_to_live_depth` of its keyframes'
    (N, 3) map points) where the move is within `see_through.align_m` / `_deg` and the moved
    pose keeps under half of `see_through.max_share` in front of the live depth (it was
    fitted to that depth: what still lies in front counts against it), its covariance grown by
    the move; None otherwise."""
    if p.see_through.align_m <= 0 or res.T_map_camera is None:
        return None
    a = align_to_live_depth(points_map, res.T_map_camera, K, depth)
    if a is None or a.shift_m > p.see_through.align_m or a.shift_deg > p.see_through.align_deg:
        return None
    if sees_through_reason(points_map, a.T_map_live, K, depth, p.see_through.max_share / 2):
        return None
    cov = res.covariance
    if cov is not None:  # the pose is known no better than the move the live depth asked for
        cov = cov.copy()
        cov[:3, :3] += a.shift_m**2 * np.eye(3)
        cov[3:, 3:] += np.radians(a.shift_deg) ** 2 * np.eye(3)
    note = f"moved {a.shift_m:.2f} m / {a.shift_deg:.1f} deg onto the live depth ({a.pairs} points)"
    return replace(res, T_map_camera=a.T_map_live, covariance=cov, stop_reason=f"{res.stop_reason}; {note}")


def checked_against_live_depth(topomap: TopoMap, res: LocalizationResult, K: NDArray[np.float64],
                               depth: NDArray[np.floating] | None, p: LocalizationParams) -> LocalizationResult:
    """The accepted `res` as it is where its pose does not see through `topomap` (its keyframes'
    stored points against the live `depth`, `see_through.max_share`), moved onto the live
    depth where that is small enough (`moved_onto_live_depth`), else refused saying why."""
    if not res.accepted or res.T_map_camera is None or depth is None:
        return res
    points = keyframe_points(topomap, list(res.keyframes))
    why = sees_through_reason(points, res.T_map_camera, K, depth, p.see_through.max_share)
    if why and (moved := moved_onto_live_depth(res, points, K, depth, p)) is not None:
        return moved
    if not why:
        return res
    kind = QueryRefusal.SEES_THROUGH
    return replace(refused(res, kind, refusal_text(kind, detail=why)), stop_reason=f"{res.stop_reason}; {why}")
