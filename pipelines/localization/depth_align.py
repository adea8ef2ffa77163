"""Align a pose to the live depth image: the map's points onto the live surface.

A pose verified across a wide view change (the second look's) can be right to 10-15 cm and
still put part of its keyframes' points in front of the live depth: wide-baseline matches
constrain the direction along the view poorly. Projective point-to-plane ICP moves the pose
so that those map points (a keyframe's stored keypoints lifted with the map's depth) lie on
the live surface: each point is paired with the live depth at the pixel it projects to, and
the pose is solved for the distance along that surface's normal. Pairs farther apart than
`max_pair_m` (occluders, free space, the other side of an edge) are left out.

Frames: `T_map_live` maps live-camera points (metres) into the map; the live camera's z looks
forward; depth images hold metres along z (NaN or <= 0: none).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from litevloc.base.geometry import F64, backproject_pixels, make_T, pixels_in_view, relative_pose_error, so3_exp

NORMAL_STEP_PX = 2  # neighbours the live surface normal is taken across (pixels)
# a neighbour farther than this (metres, or share of the depth) is across a depth edge: no normal
EDGE_M, EDGE_REL = 0.03, 0.03


@dataclass(frozen=True)
class DepthAlignment:
    """The aligned pose and what it rests on."""

    T_map_live: F64  # 4x4, the pose after alignment
    pairs: int  # map points paired with the live surface in the last iteration
    rms_m: float  # their point-to-plane distance after alignment, metres
    shift_m: float  # translation from the initial pose, metres
    shift_deg: float  # rotation from the initial pose, degrees


def _surface(depth: F64, K: F64, col: NDArray[np.int64], row: NDArray[np.int64]) -> tuple[F64, F64, NDArray[np.bool_]]:
    """Live points (N, 3) at pixels (col, row), their unit normals (N, 3) facing the camera,
    and which of them have both (valid depth, neighbours on the same surface)."""
    h, w = depth.shape
    s = NORMAL_STEP_PX
    c1, r1 = np.minimum(col + s, w - 1), np.minimum(row + s, h - 1)
    z, zx, zy = depth[row, col], depth[row, c1], depth[r1, col]
    ok = np.isfinite(z) & (z > 0) & np.isfinite(zx) & (zx > 0) & np.isfinite(zy) & (zy > 0)
    ok &= (c1 > col) & (r1 > row)
    edge = np.maximum(EDGE_M, EDGE_REL * np.where(ok, z, 0.0))
    ok &= (np.abs(zx - z) < edge) & (np.abs(zy - z) < edge)
    z, zx, zy = (np.where(ok, v, 1.0) for v in (z, zx, zy))
    q = backproject_pixels(K, np.stack([col, row], 1), z)
    qx = backproject_pixels(K, np.stack([c1, row], 1), zx)
    qy = backproject_pixels(K, np.stack([col, r1], 1), zy)
    n = np.cross(qx - q, qy - q)
    norm = np.linalg.norm(n, axis=1)
    ok &= norm > 1e-12
    n = n / np.where(norm > 1e-12, norm, 1.0)[:, None]
    n *= np.where(np.sum(n * q, axis=1) > 0, -1.0, 1.0)[:, None]  # facing the camera
    return q, n, ok


def align_to_live_depth(points_map: NDArray[np.floating], T_map_live: NDArray[np.floating],
                        K: NDArray[np.floating], depth: NDArray[np.floating], max_pair_m: float = 0.25,
                        iterations: int = 15, min_pairs: int = 20) -> DepthAlignment | None:
    """Projective point-to-plane ICP of the (N, 3) map points onto the live depth image (HxW,
    metres; intrinsics `K`) from the initial pose `T_map_live`; None when fewer than
    `min_pairs` points pair with the live surface (nothing to align on)."""
    T0 = np.asarray(T_map_live, np.float64)
    T_live_map = np.linalg.inv(T0)
    P_map = np.asarray(points_map, np.float64).reshape(-1, 3)
    D = np.asarray(depth, np.float64)
    Kf = np.asarray(K, np.float64)
    pairs, rms = 0, float("nan")
    for it in range(iterations):
        P, col, row = pixels_in_view(T_live_map, P_map, Kf, D.shape)
        q, n, ok = _surface(D, Kf, col, row)
        r = np.sum(n * (P - q), axis=1)
        # the gate narrows as the pose settles: far pairs only steer the first steps
        gate = max_pair_m * (1.0 - 0.5 * it / max(iterations - 1, 1))
        ok &= np.abs(P[:, 2] - q[:, 2]) < gate
        if ok.sum() < min_pairs:
            return None
        P, n, r = P[ok], n[ok], r[ok]
        pairs, rms = int(ok.sum()), float(np.sqrt(np.mean(r**2)))
        # left perturbation in the live frame: P' = P + w x P + v, d r / d(v, w) = (n, P x n)
        J = np.concatenate([n, np.cross(P, n)], axis=1)
        scale = max(1.4826 * float(np.median(np.abs(r))), 0.005)
        wgt = np.minimum(1.0, 1.5 * scale / np.maximum(np.abs(r), 1e-12))  # Huber
        H = J.T @ (J * wgt[:, None])
        H += 1e-6 * np.trace(H) * np.eye(6)  # a plane leaves directions unconstrained: do not move along them
        d = -np.linalg.solve(H, J.T @ (wgt * r))
        T_live_map = make_T(so3_exp(d[3:]), d[:3]) @ T_live_map
        if np.linalg.norm(d[:3]) < 1e-4 and np.linalg.norm(d[3:]) < 1e-4:
            break
    T = np.linalg.inv(T_live_map)
    shift_m, shift_deg = relative_pose_error(T, T0)
    return DepthAlignment(T, pairs, rms, shift_m, shift_deg)
