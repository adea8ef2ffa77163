"""Depth at sub-pixel keypoints, with validity and discontinuity rejection.

Method: bilinear interpolation over the 2x2 neighbourhood of each keypoint, accepted only
if all four neighbours are valid (finite, in (min_depth, max_depth]) and their spread is
small (max - min <= abs_tol + rel_tol * min). Why: bilinear is unbiased on smooth surfaces
(nearest-pixel lookup adds up to half a pixel of lateral error), and the spread test
rejects keypoints on depth edges, where interpolation would invent points floating
between foreground and background — exactly where detectors like to fire.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from litevloc.base.params.localization import DepthLookupParams


def depth_at(
    depth: NDArray[np.floating], uv: NDArray[np.floating], params: DepthLookupParams = DepthLookupParams()
) -> NDArray[np.float32]:
    """Depth (metres) at each (u, v) pixel of an HxW depth image; NaN where rejected.

    Args:
        depth: HxW metres, NaN or <= 0 invalid.
        uv: (N, 2) pixel coordinates (x = column, y = row), pixel centres at integers.
    Returns:
        (N,) float32 depths, NaN for keypoints outside the image, on holes or on edges.
    """
    d = np.asarray(depth, dtype=np.float32)
    pts = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    h, w = d.shape
    out = np.full(len(pts), np.nan, dtype=np.float32)
    if len(pts) == 0:
        return out
    u, v = pts[:, 0], pts[:, 1]
    inside = np.isfinite(u) & np.isfinite(v) & (u >= 0) & (v >= 0) & (u <= w - 1) & (v <= h - 1)
    u0 = np.clip(np.floor(u), 0, max(w - 2, 0)).astype(np.intp)
    v0 = np.clip(np.floor(v), 0, max(h - 2, 0)).astype(np.intp)
    u1 = np.minimum(u0 + 1, w - 1)
    v1 = np.minimum(v0 + 1, h - 1)
    n = np.stack([d[v0, u0], d[v0, u1], d[v1, u0], d[v1, u1]], axis=1).astype(np.float64)
    with np.errstate(invalid="ignore"):
        valid = np.all(np.isfinite(n) & (n > params.min_depth) & (n <= params.max_depth), axis=1)
        lo = np.min(n, axis=1)
        hi = np.max(n, axis=1)
        smooth = (hi - lo) <= params.abs_tol + params.rel_tol * lo
    ok = inside & valid & smooth
    fu = np.clip(u - u0, 0, 1)
    fv = np.clip(v - v0, 0, 1)
    val = (n[:, 0] * (1 - fu) * (1 - fv) + n[:, 1] * fu * (1 - fv) + n[:, 2] * (1 - fu) * fv + n[:, 3] * fu * fv)
    out[ok] = val[ok].astype(np.float32)
    return out
