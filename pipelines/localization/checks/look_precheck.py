"""The second look's pre-check: a candidate the full-resolution matcher cannot verify, found cheaply.

LightGlue over two full-resolution keypoint sets is the second look's largest cost (about 14
first-look extractions per pair). Before it runs, the query's and the keyframe's full-resolution
features are matched by mutual nearest neighbours (no model) and lifted with the live depth into
one PnP + RANSAC: a pair whose consensus stays below `second_look.precheck_min_inliers` shares too
little for the matcher's inliers to reach the PnP floor, and is not matched.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from litevloc.base.geometry import backproject_pixels
from litevloc.base.params.localization import LocalizationParams
from litevloc.pipelines.depth_lookup import depth_at
from litevloc.pipelines.guided_matching import mutual_nn_pairs
from litevloc.pipelines.pnp import solve_pnp
from litevloc.pipelines.topomap.types import FeatureSet


def precheck_inliers(live: FeatureSet, depth: NDArray[np.float32], K: NDArray[np.float64], ref: FeatureSet,
                     K_ref: NDArray[np.float64], p: LocalizationParams) -> tuple[int, int]:
    """(mutual nearest neighbours, their PnP + RANSAC inliers) between the live features `live`
    (pixels of the live image, lifted with `depth` (H, W) metres and intrinsics `K`) and a
    keyframe's `ref` (pixels of its image, intrinsics `K_ref`), under `p.pnp`'s reprojection
    threshold with no acceptance gate; 0 inliers where RANSAC finds no pose."""
    i_live, i_ref = mutual_nn_pairs(live.descriptors, ref.descriptors, p.second_look.precheck_min_similarity)
    uv = np.asarray(live.keypoints, dtype=np.float64).reshape(-1, 2)[i_live]
    z = depth_at(depth, uv, p.depth).astype(np.float64)
    ok = np.isfinite(z)
    if ok.sum() < 4:
        return len(i_live), 0
    pts = backproject_pixels(K, uv[ok], z[ok])
    kp_ref = np.asarray(ref.keypoints, dtype=np.float64).reshape(-1, 2)[i_ref[ok]]
    res = solve_pnp(pts, kp_ref, K_ref, replace(p.pnp, min_inliers=4, min_inlier_ratio=0.0,
                                                 max_median_reprojection_px=float("inf")))
    return len(i_live), res.n_inliers if res.T_target_source is not None else 0
