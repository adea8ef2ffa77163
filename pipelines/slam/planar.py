"""Planar motion of a ground robot's base as pose-graph edges (`slam.planar`).

A wheeled or legged robot's base_link moves on the floor: between two consecutive keyframes
it turns about its z axis and moves along x and y, but its height, roll and pitch change only
by the floor's unevenness and the gait's bob. Each such pair gets an edge that says so: in
base_link, height, roll and pitch unchanged with sigmas `sigma_height_m`, `sigma_tilt_deg`,
and x, y, yaw free (a sigma so large the measured value carries no weight; it is taken from
the keyframes' initial poses, so the edge starts at zero error on those axes). The 6x6
covariance is moved from base_link into the camera frame by the adjoint of `T_camera_base`
(GTSAM's tangent order: rotation, then translation), as the odometry edges are.

Only keyframes of one chain are paired: a chain joined by loops alone keeps its own frame.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence

import numpy as np

from litevloc.base.geometry import invert, make_T, so3_exp
from litevloc.base.params.slam import SlamPlanarParams
from litevloc.pipelines.slam.graph import GraphNode
from litevloc.pipelines.slam.odometry import adjoint
from litevloc.pipelines.slam.types import F64, Edge

_FREE_SIGMA = 100.0  # metres and radians on the axes a planar robot moves freely along


def planar_motion(T_base_a_base_b: F64) -> F64:
    """The motion (4x4) with its height, roll and pitch removed: the yaw about base z and the
    x, y translation kept."""
    M = np.asarray(T_base_a_base_b, np.float64)
    yaw = float(np.arctan2(M[1, 0], M[0, 0]))
    return make_T(so3_exp(np.array([0.0, 0.0, yaw])), np.array([M[0, 3], M[1, 3], 0.0]))


def planar_edges(keyframes: Sequence[GraphNode], T_base_camera: F64, params: SlamPlanarParams) -> list[Edge]:
    """One "planar" edge between each pair of consecutive keyframes (id order) of one chain,
    camera to camera like the other edges (see the module docstring); none when disabled."""
    if not params.enabled:
        return []
    T_bc = np.asarray(T_base_camera, np.float64)
    T_cb = invert(T_bc)
    s_h, s_r = params.sigma_height_m, float(np.radians(params.sigma_tilt_deg))
    cov_base = np.diag([s_r**2, s_r**2, _FREE_SIGMA**2, _FREE_SIGMA**2, _FREE_SIGMA**2, s_h**2])
    Ad = adjoint(T_cb)
    cov = Ad @ cov_base @ Ad.T
    out: list[Edge] = []
    ordered = sorted(keyframes, key=lambda k: k.id)
    for a, b in itertools.pairwise(ordered):
        if a.chain != b.chain:
            continue
        M = T_bc @ invert(a.T_init) @ b.T_init @ T_cb
        out.append(Edge(a.id, b.id, T_cb @ planar_motion(M) @ T_bc, cov.copy(), "planar"))
    return out
