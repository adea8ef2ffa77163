"""Does a live pose see through the map? The map's 3D points against the live depth image.

Under a right pose, a keyframe's points (its stored keypoints lifted with the map's depth) that
fall in the live image lie on the live depth surface, or behind it where something occludes
them. A point the pose puts clearly *in front of* that surface would be seen where the live
camera sees farther: free space through a mapped surface. A pose verified on one repeated or
thin structure (leaflets on two shelves) puts many of the keyframes' other points there.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from litevloc.base.geometry import backproject_pixels, pixels_in_view
from litevloc.pipelines.topomap.types import TopoMap

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
