"""What the goal placement finds: a goal image's place (`GoalResult`), one keyframe's PnP of it
(`GoalPose`), the candidates it verifies (`Candidate`) and the measures of their PnP support
(`plane_rms`, `horizontal_share`, `distinctive_support`)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from litevloc.base.params.navigation import GoalParams


@dataclass(frozen=True)
class GoalResult:
    """Where a goal image is: its map node (None: not placed, see `reason`) and, where the
    map has keypoint depth, the goal camera's metric pose in the map (4x4 `T_map_camera`)."""

    node: int | None
    inliers: int
    reason: str
    candidates: tuple[tuple[int, float, int], ...] = ()  # (node, similarity, inliers)
    T_map_goal: NDArray[np.float64] | None = None  # None: no metric pose (no keypoint depth, or PnP failed)
    pose_inliers: int = 0


@dataclass(frozen=True)
class GoalPose:
    """PnP of a goal image against one keyframe's depth-lifted keypoints.

    T_node_goal: 4x4 goal camera pose in the keyframe camera's frame (metres); None when
    there is no depth, too few inliers or the pose is implausibly far.
    inliers: PnP inliers; where PnP did not run (too few matches with depth), those matches.
    plane_rms_m: RMS distance (m) of the inliers' 3D points from their best-fitting plane;
    NaN without a pose. Near zero: the whole support is one flat patch (a poster, a sign,
    one wall), which can hang at several places.
    support_points: (M, 3) the PnP inliers' 3D points in the keyframe camera frame (metres);
    empty without a pose.
    """

    T_node_goal: NDArray[np.float64] | None
    inliers: int
    plane_rms_m: float = float("nan")
    support_points: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 3)))


def plane_rms(points: NDArray[np.float64]) -> float:
    """RMS distance (m) of (N, 3) points from their least-squares plane (the smallest
    singular value of the centred points over sqrt(N)); NaN for fewer than 3 points."""
    if len(points) < 3:
        return float("nan")
    c = points - points.mean(axis=0)
    return float(np.linalg.svd(c, compute_uv=False)[-1] / np.sqrt(len(points)))


def horizontal_share(points_map: NDArray[np.float64], up: NDArray[np.float64], band_m: float = 0.04) -> float:
    """Largest share (0-1) of (N, 3) map points whose heights along `up` (unit 3-vector)
    lie within one band of `band_m` metres: the part of a support that rests on one
    horizontal surface (floor or ceiling tiles, which repeat everywhere). NaN for no points."""
    if len(points_map) == 0:
        return float("nan")
    h = np.sort(np.asarray(points_map, np.float64) @ np.asarray(up, np.float64))
    in_band = np.searchsorted(h, h + band_m, side="right") - np.arange(len(h))
    return float(in_band.max() / len(h))


def distinctive_support(points_map: NDArray[np.float64], up: NDArray[np.float64], band_m: float) -> int:
    """PnP support points (N, 3, map frame) that say which place an image shows: all but those in
    the densest horizontal band of `band_m` metres (floor or ceiling tiles, which repeat in every
    room and, shifted by a tile, fit at several spots of one room); `band_m` 0: all of them."""
    if band_m <= 0 or len(points_map) == 0:
        return len(points_map)
    return round(len(points_map) * (1.0 - horizontal_share(points_map, up, band_m)))


@dataclass(frozen=True)
class Candidate:
    """A keyframe the goal image was verified against: its essential-matrix inliers and, where
    its depth gave one and nothing doubts it, the goal camera's metric pose (4x4, map frame)."""

    node: int
    similarity: float
    inliers: int  # essential-matrix inliers
    T_map_goal: NDArray[np.float64] | None
    pose_inliers: int
    plane_rms_m: float = float("nan")
    support_points: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 3)))  # GoalPose's, node frame
    pose_doubt: str = ""  # why its PnP pose was dropped (`pose_doubt`), "" if it was not
    tiles: tuple[int, int] | None = None  # (distinctive, all) PnP support where it rests on floor/ceiling tiles

    def planar(self, params: GoalParams) -> bool:
        """True when the candidate's PnP support is one flat patch (see `GoalParams.planar_rms_m`)."""
        return params.planar_rms_m > 0 and bool(self.plane_rms_m < params.planar_rms_m)

    def needed(self, params: GoalParams) -> float:
        """Essential-matrix inliers this candidate needs to verify a place (none suffice for a
        match on floor or ceiling tiles alone)."""
        if self.tiles is not None:
            return float("inf")
        return params.min_inliers * (params.planar_factor if self.planar(params) else 1.0)
