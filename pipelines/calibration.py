"""Colour-camera calibration of an RGB-D sensor from posed frames (7-Scenes style data).

Problem: datasets like 7-Scenes publish one approximate intrinsics matrix (that of the
depth camera) and ground-truth poses of the *depth* camera (KinectFusion), while the
colour camera has its own intrinsics and sits a few cm away. This module estimates

* the colour intrinsics `K_color` (fx, fy, cx, cy; pinhole, with the lens's radial distortion
  k1, k2 too when `estimate_distortion`), and
* the rigid extrinsic `T_color_depth` (maps depth-camera points to the colour camera),

given colour images, raw depth images (in the depth camera), depth-camera poses and the
depth intrinsics `K_depth`, which are taken as correct.

Method (bundle-adjustment-like, with the ground-truth motion fixed):
1. SIFT keypoints per colour image; pairs of frames `a, b` a few frames apart are matched
   (nearest neighbour + ratio test), outliers removed by a calibration-free RANSAC
   fundamental-matrix fit.
2. A colour keypoint `u_a` is lifted to 3D through the *raw* depth image: with the current
   guess of its depth `z` (from the previous round), the point `z K_color^-1 u_a` is moved
   into the depth camera and projected with `K_depth`; the depth there (bilinear, rejected
   on holes and edges) gives the 3D point `X_d` in the depth camera. Because the depth
   pixel depends smoothly on the calibration, the depth/colour association itself is
   optimised too (this is what the extrinsic translation is mostly observed through).
3. `X_d` is moved by the known motion `T_db_da = inv(T_world_db) T_world_da`, into the
   colour camera of `b`, and projected with `K_color`; the residual is the pixel distance
   to the matched `u_b`. Both directions are used.
4. `scipy.optimize.least_squares` (trust region, Huber loss) minimises over the 10
   parameters (fx, fy, cx, cy, rotation vector, translation); a few outer rounds refresh
   the depth guesses and the inlier set.

Units: pixels, metres, radians. Poses follow `pipelines.geometry` (`T_a_b` maps b to a).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from litevloc.base.geometry import (
    invert,
    make_T,
    so3_exp,
    so3_log,
    undistort_normalized,
)
from litevloc.base.params.calibration import CalibrationParams, ColorDepthCalibration

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class Correspondences:
    """Matched colour keypoints of frame pairs, one direction (a -> b) per row.

    frame_a: (N,) int index into the depth list; uv_a, uv_b: (N, 2) float64 pixels;
    T_db_da: (N, 4, 4) ground-truth motion of the depth camera between the two frames.
    """

    frame_a: NDArray[np.intp]
    uv_a: F64
    uv_b: F64
    T_db_da: F64


@dataclass(frozen=True)
class CalibrationResult:
    calibration: ColorDepthCalibration
    n_pairs: int
    n_residuals: int  # correspondences in the last round
    rms_before_px: float  # of the initial guess, on the last round's inliers
    rms_after_px: float
    median_before_px: float
    median_after_px: float
    std: dict[str, float] = field(default_factory=dict)  # 1-sigma from the Jacobian (inlier noise)


# ----------------------------------------------------------------------------- matching
def match_pairs(
    colors: Sequence[NDArray[np.uint8]], T_world_depth: NDArray[np.floating], params: CalibrationParams,
) -> tuple[Correspondences, int]:
    """SIFT matches between frame pairs (both directions); returns (rows, number of pairs used).

    colors: N HxWx3 uint8 RGB; T_world_depth: (N, 4, 4) depth-camera poses.
    """
    T = np.asarray(T_world_depth, dtype=np.float64)
    n = len(colors)
    pairs = [(a, a + g) for g in params.pair_gaps for a in range(n - g)
             if np.linalg.norm(T[a, :3, 3] - T[a + g, :3, 3]) >= params.min_parallax_m]
    if len(pairs) > params.max_pairs:
        pairs = [pairs[i] for i in np.linspace(0, len(pairs) - 1, params.max_pairs).round().astype(int)]
    sift = cv2.SIFT_create(nfeatures=params.sift_features)  # type: ignore[attr-defined]
    cache: dict[int, tuple[F64, NDArray[np.float32]]] = {}

    def feats(i: int) -> tuple[F64, NDArray[np.float32]]:
        if i not in cache:
            kps, desc = sift.detectAndCompute(cv2.cvtColor(colors[i], cv2.COLOR_RGB2GRAY), None)
            cache[i] = (np.array([k.pt for k in kps], dtype=np.float64).reshape(-1, 2),
                        desc if desc is not None else np.zeros((0, 128), np.float32))
        return cache[i]

    bf = cv2.BFMatcher(cv2.NORM_L2)
    fa, ua, ub, Ts = [], [], [], []
    used = 0
    for a, b in pairs:
        (ka, da), (kb, db) = feats(a), feats(b)
        if len(ka) < params.min_matches or len(kb) < params.min_matches:
            continue
        knn = bf.knnMatch(da, db, k=2)
        good = [m[0] for m in knn if len(m) == 2 and m[0].distance < params.ratio * m[1].distance]
        if len(good) < params.min_matches:
            continue
        pa = ka[[m.queryIdx for m in good]]
        pb = kb[[m.trainIdx for m in good]]
        _, mask = cv2.findFundamentalMat(pa, pb, cv2.FM_RANSAC, params.fundamental_px, 0.999)
        if mask is None or int(mask.sum()) < params.min_matches:
            continue
        keep = mask.ravel().astype(bool)
        pa, pb = pa[keep], pb[keep]
        T_db_da = invert(T[b]) @ T[a]
        for i, pi, pj, Tji in ((a, pa, pb, T_db_da), (b, pb, pa, invert(T_db_da))):
            fa.append(np.full(len(pi), i, dtype=np.intp))
            ua.append(pi)
            ub.append(pj)
            Ts.append(np.broadcast_to(Tji, (len(pi), 4, 4)))
        used += 1
    if not fa:
        raise ValueError("no frame pair had enough verified SIFT matches: check the frames overlap and are textured")
    return Correspondences(np.concatenate(fa), np.concatenate(ua), np.concatenate(ub), np.concatenate(Ts)), used


# ----------------------------------------------------------------------------- model
def _unpack(x: F64) -> tuple[F64, F64]:
    K = np.array([[x[0], 0.0, x[2]], [0.0, x[1], x[3]], [0.0, 0.0, 1.0]])
    return K, make_T(so3_exp(x[4:7]), x[7:10])


def _pack(cal: ColorDepthCalibration) -> F64:
    T = cal.T_color_depth()
    return np.array([cal.color_fx, cal.color_fy, cal.color_cx, cal.color_cy, *so3_log(T[:3, :3]), *T[:3, 3],
                     cal.color_k1, cal.color_k2])


def _color_rays(x: F64, uv: F64) -> F64:
    """(N, 3) rays (z = 1) of colour pixels `uv` (N, 2) under the parameters `x`
    (pinhole + radial distortion k1, k2, undone by `base.geometry.undistort_normalized`)."""
    xd = np.stack([(uv[:, 0] - x[2]) / x[0], (uv[:, 1] - x[3]) / x[1]], axis=1)
    xn = undistort_normalized(xd, float(x[10]), float(x[11]))
    return np.concatenate([xn, np.ones((len(xn), 1))], axis=1)


def _color_project(x: F64, X: F64) -> F64:
    """(N, 2) colour pixels of colour-camera points X (N, 3) under the parameters `x`
    (OpenCV `projectPoints` with the pinhole and radial k1, k2)."""
    K = np.array([[x[0], 0.0, x[2]], [0.0, x[1], x[3]], [0.0, 0.0, 1.0]])
    dist = np.array([x[10], x[11], 0.0, 0.0, 0.0])
    X64 = np.asarray(X, np.float64).reshape(-1, 3)
    uv, _ = cv2.projectPoints(X64.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, dist)
    out = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    out[X64[:, 2] == 0.0] = np.nan  # OpenCV projects z = 0 to a finite pixel; there is none
    return out


def _bilinear(depths: NDArray[np.float32], frame: NDArray[np.intp], uv: F64, edge_rel_tol: float) -> F64:
    """Depth at (u, v) of depths[frame] (bilinear; NaN outside, on holes or on edges)."""
    _, h, w = depths.shape
    u, v = uv[:, 0], uv[:, 1]
    ok = np.isfinite(u) & np.isfinite(v) & (u >= 0) & (v >= 0) & (u <= w - 1.001) & (v <= h - 1.001)
    u0 = np.clip(np.floor(np.nan_to_num(u)), 0, w - 2).astype(np.intp)
    v0 = np.clip(np.floor(np.nan_to_num(v)), 0, h - 2).astype(np.intp)
    n = np.stack([depths[frame, v0, u0], depths[frame, v0, u0 + 1],
                  depths[frame, v0 + 1, u0], depths[frame, v0 + 1, u0 + 1]], axis=1).astype(np.float64)
    with np.errstate(invalid="ignore"):
        lo, hi = n.min(axis=1), n.max(axis=1)
        ok &= np.isfinite(lo) & (hi - lo <= edge_rel_tol * lo)
    fu = np.clip(np.nan_to_num(u) - u0, 0, 1)
    fv = np.clip(np.nan_to_num(v) - v0, 0, 1)
    z = n[:, 0] * (1 - fu) * (1 - fv) + n[:, 1] * fu * (1 - fv) + n[:, 2] * (1 - fu) * fv + n[:, 3] * fu * fv
    return np.where(ok, z, np.nan)


def lookup_color_depth(
    x: F64, corr: Correspondences, depths: NDArray[np.float32], K_depth: F64, z_guess: F64, edge_rel_tol: float,
    iterations: int = 2,
) -> F64:
    """Depth (metres, along the colour camera's z) of each row's colour keypoint `uv_a`.

    The keypoint's ray at depth `z_guess` is moved into the depth camera and projected
    there; the raw depth at that pixel (bilinear; NaN on holes/edges) gives the 3D point,
    whose colour-camera z is the next guess (`iterations` times).
    """
    _, T_cd = _unpack(x)
    T_dc = invert(T_cd)
    rays = _color_rays(x, corr.uv_a)
    z = np.asarray(z_guess, dtype=np.float64)
    for _ in range(iterations):
        Xd_guess = (rays * np.nan_to_num(z, nan=1.0)[:, None]) @ T_dc[:3, :3].T + T_dc[:3, 3]
        with np.errstate(invalid="ignore", divide="ignore"):
            p = Xd_guess[:, :2] / Xd_guess[:, 2:3] * [K_depth[0, 0], K_depth[1, 1]] + [K_depth[0, 2], K_depth[1, 2]]
        zd = _bilinear(depths, corr.frame_a, p, edge_rel_tol)
        Xd = np.stack([(p[:, 0] - K_depth[0, 2]) / K_depth[0, 0] * zd,
                       (p[:, 1] - K_depth[1, 2]) / K_depth[1, 1] * zd, zd], axis=1)
        z = Xd @ T_cd[2, :3] + T_cd[2, 3]
    return z


def reprojection_residuals(x: F64, corr: Correspondences, z_color: F64) -> F64:
    """(N, 2) pixel residuals: `uv_a` lifted at colour depth `z_color` (N,), moved by the
    ground-truth motion conjugated into the colour camera, projected, minus `uv_b`.

    Smooth in x (the depth association is held fixed; `lookup_color_depth` refreshes it).
    """
    _, T_cd = _unpack(x)
    T_dc = invert(T_cd)
    Xc = _color_rays(x, corr.uv_a) * z_color[:, None]
    Xd = Xc @ T_dc[:3, :3].T + T_dc[:3, 3]
    Xdb = np.einsum("nij,nj->ni", corr.T_db_da[:, :3, :3], Xd) + corr.T_db_da[:, :3, 3]
    Xcb = Xdb @ T_cd[:3, :3].T + T_cd[:3, 3]
    return np.asarray(_color_project(x, Xcb) - corr.uv_b, dtype=np.float64)


def _rows(corr: Correspondences, rows: NDArray[np.intp]) -> Correspondences:
    return Correspondences(corr.frame_a[rows], corr.uv_a[rows], corr.uv_b[rows], corr.T_db_da[rows])


def calibrate_color_depth(
    colors: Sequence[NDArray[np.uint8]],
    depths: Sequence[NDArray[np.floating]],
    T_world_depth: NDArray[np.floating],
    K_depth: NDArray[np.floating],
    init: ColorDepthCalibration,
    params: CalibrationParams = CalibrationParams(),
    corr: Correspondences | None = None,
) -> CalibrationResult:
    """Estimate colour intrinsics and T_color_depth (see the module docstring).

    Args:
        colors: N HxWx3 uint8 RGB colour images.
        depths: N HxW float32 depth images in metres, NaN invalid, in the DEPTH camera.
        T_world_depth: (N, 4, 4) depth-camera poses (ground truth).
        K_depth: 3x3 depth intrinsics (taken as correct).
        init: starting guess (e.g. K_color = K_depth, identity extrinsic).
        corr: precomputed correspondences (else SIFT matching of `colors`).
    """
    if not (len(colors) == len(depths) == len(T_world_depth)):
        raise ValueError("colors, depths and T_world_depth must have the same length")
    Kd: F64 = np.asarray(K_depth, dtype=np.float64)
    D = np.stack([np.where(np.asarray(d) > 0, np.asarray(d, dtype=np.float32), np.nan) for d in depths])
    D[(params.min_depth_m > D) | (params.max_depth_m < D)] = np.nan
    n_pairs = -1
    if corr is None:
        corr, n_pairs = match_pairs(colors, T_world_depth, params)
    x0 = _pack(init)
    x = x0.copy()
    scale = np.array([10.0, 10.0, 10.0, 10.0, 0.01, 0.01, 0.01, 0.01, 0.01, 0.01, 0.01, 0.01])
    z = lookup_color_depth(x, corr, D, Kd, _bilinear(D, corr.frame_a, corr.uv_a, 1e9), params.edge_rel_tol)
    keep = np.isfinite(z)
    free = np.r_[np.arange(7), np.arange(7, 10) if params.estimate_translation else [],
                 [10, 11] if params.estimate_distortion else []].astype(np.intp)
    sol = None
    for rnd in range(params.rounds):
        rows = np.flatnonzero(keep)
        sub, zs = _rows(corr, rows), z[rows]

        def fun(xf: F64, sub: Correspondences = sub, zs: F64 = zs, base: F64 = x) -> F64:
            xx = base.copy()
            xx[free] = xf
            return reprojection_residuals(xx, sub, zs).ravel()

        sol = least_squares(fun, x[free], loss="huber", f_scale=params.huber_px, x_scale=scale[free],
                            method="trf", max_nfev=100)
        x = x.copy()
        x[free] = sol.x
        if rnd == params.rounds - 1:
            break
        z = lookup_color_depth(x, corr, D, Kd, z, params.edge_rel_tol)
        err = np.linalg.norm(reprojection_residuals(x, corr, np.nan_to_num(z, nan=1.0)), axis=1)
        keep = np.isfinite(z) & np.isfinite(err) & (err < params.outlier_px)
        if keep.sum() < 50:
            raise ValueError(f"calibration: only {int(keep.sum())} consistent correspondences left")
    assert sol is not None
    sub, zs = _rows(corr, rows), z[rows]
    r_after = reprojection_residuals(x, sub, zs)
    z0 = lookup_color_depth(x0, sub, D, Kd, zs, params.edge_rel_tol)
    r_before = reprojection_residuals(x0, sub, z0)
    e_after = np.linalg.norm(r_after, axis=1)
    e_before = np.linalg.norm(r_before, axis=1)
    names = ["color_fx", "color_fy", "color_cx", "color_cy", "rot_x", "rot_y", "rot_z", "t_x", "t_y", "t_z",
             "color_k1", "color_k2"]
    std: dict[str, float] = {}
    try:
        J = sol.jac
        inl = np.isfinite(r_after).all(axis=1) & (e_after < 3 * params.huber_px)
        sigma2 = float(np.mean(r_after[inl] ** 2)) if inl.any() else float("nan")
        cov = np.linalg.pinv(J.T @ J) * sigma2
        std = {names[int(k)]: float(np.sqrt(max(cov[i, i], 0.0))) for i, k in enumerate(free)}
    except (np.linalg.LinAlgError, ValueError):
        pass
    K, T_cd = _unpack(x)
    return CalibrationResult(
        ColorDepthCalibration.from_arrays(K, T_cd, (float(x[10]), float(x[11]))), n_pairs, len(rows),
        float(np.sqrt(np.nanmean(e_before ** 2))), float(np.sqrt(np.nanmean(e_after ** 2))),
        float(np.nanmedian(e_before)), float(np.nanmedian(e_after)), std,
    )
