"""Matched keypoints moved onto the same surface point: plane-induced patch alignment.

A detector fires on the middle of a blob as the image shows it. On a texture seen at a grazing
angle (a corridor's floor) the blob is foreshortened, more so on its far side, and the keypoint
of the same feature lands on slightly different surface points in two views: measured on the
simulator, the nearer view's point 0.4-0.5 % nearer than the farther view's, which the 3D terms
of an edge read as a motion 1-2 % too long (`bench/vo_bias.py`). Here the source keypoint is
kept and its match in the target is re-found: the source's patch is warped into the target by
the homography of the local surface plane (from the source's depth) under the estimated motion,
and the target position is refined by Lucas-Kanade over a translation (the warp's shape fixed),
so that both keypoints name the point the source's depth was read at.

Frames: `T_t_s` maps source camera points into the target camera; pixels (u, v), centres at
integers; depth in metres.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from litevloc.base.params.slam import KeypointAlignmentParams

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]
# a fitted plane seen more edge-on than this (cosine between its normal and the view ray) spans a depth edge
MIN_VIEW_COSINE = 0.05


@dataclass(frozen=True, eq=False)
class AlignmentView:
    """What alignment needs of one frame: grey image and its gradients (HxW float32, intensity
    units, gradient per pixel), depth (HxW float32 metres, NaN = none) and intrinsics (3x3)."""

    gray: F32
    grad_u: F32
    grad_v: F32
    depth: F32
    K: F64


def alignment_view(color: NDArray[np.uint8], depth: NDArray[np.floating], K: F64) -> AlignmentView:
    """The grey image (from HxWx3 RGB or HxW), its gradients and the depth of one frame."""
    gray = (cv2.cvtColor(color, cv2.COLOR_RGB2GRAY) if color.ndim == 3 else color).astype(np.float32)
    # Scharr's kernel sums to 32 per pixel of offset: scaled to intensity per pixel
    gu = np.asarray(cv2.Scharr(gray, cv2.CV_32F, 1, 0) / 32.0, np.float32)
    gv = np.asarray(cv2.Scharr(gray, cv2.CV_32F, 0, 1) / 32.0, np.float32)
    return AlignmentView(gray, gu, gv, np.asarray(depth, np.float32), np.asarray(K, np.float64))


def surface_normals(depth: F32, K: F64, uv: F64, radius_px: int, max_rms_rel: float) -> F64:
    """(M, 3) unit normals (camera frame, facing the camera) of the surface at pixels `uv` (M, 2):
    a plane fitted to the depth's points on a (2r+1)^2 grid, stride r/2 (at least 1) around each
    pixel; NaN rows where a sample has no depth, the plane's RMS residual exceeds `max_rms_rel`
    times the depth (a corner) or the plane is seen edge-on (a depth edge's two sides)."""
    h, w = depth.shape
    step = max(radius_px // 2, 1)
    offs = np.arange(-radius_px, radius_px + 1, step)
    ou, ov = np.meshgrid(offs, offs)
    cu = np.rint(uv[:, 0])[:, None] + ou.ravel()[None, :]
    cv_ = np.rint(uv[:, 1])[:, None] + ov.ravel()[None, :]
    inside = np.all((cu >= 0) & (cu < w) & (cv_ >= 0) & (cv_ < h), axis=1)
    z = depth[np.clip(cv_, 0, h - 1).astype(np.intp), np.clip(cu, 0, w - 1).astype(np.intp)].astype(np.float64)
    ok = inside & np.all(np.isfinite(z) & (z > 0), axis=1)
    out = np.full((len(uv), 3), np.nan)
    if not ok.any():
        return out
    z, cu, cv_ = z[ok], cu[ok], cv_[ok]
    P = np.stack([(cu - K[0, 2]) * z / K[0, 0], (cv_ - K[1, 2]) * z / K[1, 1], z], axis=2)  # (m, S, 3)
    c = P.mean(axis=1, keepdims=True)
    _, s, vt = np.linalg.svd(P - c, full_matrices=False)
    n = vt[:, 2, :]
    n *= -np.sign(np.einsum("ij,ij->i", n, c[:, 0, :]))[:, None]  # towards the camera
    rms = s[:, 2] / np.sqrt(P.shape[1])
    view = np.abs(np.einsum("ij,ij->i", n, c[:, 0, :])) / np.linalg.norm(c[:, 0, :], axis=1)
    good = (rms <= max_rms_rel * c[:, 0, 2]) & (view >= MIN_VIEW_COSINE)
    idx = np.nonzero(ok)[0]
    out[idx[good]] = n[good]
    return out


def plane_homographies(K_s: F64, K_t: F64, T_t_s: F64, points_s: F64, normals_s: F64) -> F64:
    """(M, 3, 3) homographies from source to target pixels of the planes through `points_s`
    (M, 3, source camera frame) with `normals_s` (M, 3): K_t (R + t n^T / d) K_s^-1, d = n . X."""
    R, t = T_t_s[:3, :3], T_t_s[:3, 3]
    d = np.einsum("ij,ij->i", normals_s, points_s)
    A = R[None] + t[None, :, None] * (normals_s / d[:, None])[:, None, :]
    return np.asarray(K_t[None] @ A @ np.linalg.inv(K_s)[None], np.float64)


def _sample(img: F32, u: F64, v: F64) -> F32:
    """Bilinear samples of `img` at (u, v) arrays of any one shape (2D, at most 32767 per axis)."""
    return np.asarray(cv2.remap(img, u.astype(np.float32), v.astype(np.float32), cv2.INTER_LINEAR,
                                borderMode=cv2.BORDER_REPLICATE), np.float32)


def align_keypoints(source: AlignmentView, target: AlignmentView, uv_s: F64, points_s: F64, uv_t: F64,
                    T_t_s: F64, params: KeypointAlignmentParams) -> tuple[F64, NDArray[np.bool_]]:
    """Target keypoints (M, 2) moved onto the surface points of the source keypoints `uv_s`
    (M, 2; `points_s` (M, 3) their lifted points, source camera frame), starting from the
    matched target keypoints `uv_t` (M, 2), under the estimated motion `T_t_s` (only the warp's
    shape comes from it: a pose a few centimetres off changes the result by a small fraction of
    a pixel). Returns the moved keypoints and which of them converged (textured in both
    directions, a shift within `params.max_shift_px`, zero-mean NCC of the patches at least
    `params.min_ncc`); the others are returned unmoved."""
    m = len(uv_s)
    out = np.array(uv_t, np.float64, copy=True)
    done = np.zeros(m, bool)
    if m == 0:
        return out, done
    n = surface_normals(source.depth, source.K, uv_s, params.normal_radius_px, params.max_plane_rms)
    has = np.all(np.isfinite(n), axis=1) & np.all(np.isfinite(points_s), axis=1)
    if not has.any():
        return out, done
    idx = np.nonzero(has)[0]
    H = plane_homographies(source.K, target.K, T_t_s, points_s[idx], n[idx])
    r = params.patch_radius_px
    g = np.arange(-r, r + 1, dtype=np.float64)
    gu, gv = (a.ravel() for a in np.meshgrid(g, g))
    su = uv_s[idx, 0:1] + gu[None]
    sv = uv_s[idx, 1:2] + gv[None]
    S = _sample(source.gray, su, sv).astype(np.float64)
    # the warp's shape around the keypoint: target offsets of the patch's pixels from its centre's image
    q = np.einsum("mij,mjk->mik", H, np.stack([su, sv, np.ones_like(su)], axis=1))
    qu, qv = q[:, 0] / q[:, 2], q[:, 1] / q[:, 2]
    hc = np.einsum("mij,mj->mi", H, np.column_stack([uv_s[idx], np.ones(len(idx))]))
    du = qu - (hc[:, 0] / hc[:, 2])[:, None]
    dv = qv - (hc[:, 1] / hc[:, 2])[:, None]
    start = uv_t[idx].astype(np.float64)
    pos = start.copy()
    Sc = S - S.mean(axis=1, keepdims=True)
    s_std = np.sqrt((Sc ** 2).mean(axis=1)) + 1e-6
    h, w = target.gray.shape
    for _ in range(params.iterations):
        uu, vv = pos[:, 0:1] + du, pos[:, 1:2] + dv
        T = _sample(target.gray, uu, vv).astype(np.float64)
        Ju = _sample(target.grad_u, uu, vv).astype(np.float64)
        Jv = _sample(target.grad_v, uu, vv).astype(np.float64)
        Tc = T - T.mean(axis=1, keepdims=True)
        t_std = np.sqrt((Tc ** 2).mean(axis=1)) + 1e-6
        res = Tc - Sc * (t_std / s_std)[:, None]  # bias and gain of the exposure taken out
        Ju -= Ju.mean(axis=1, keepdims=True)
        Jv -= Jv.mean(axis=1, keepdims=True)
        a, b, cc = (Ju * Ju).sum(1), (Ju * Jv).sum(1), (Jv * Jv).sum(1)
        ru, rv = (Ju * res).sum(1), (Jv * res).sum(1)
        det = a * cc - b * b
        safe = np.where(np.abs(det) > 1e-9, det, 1.0)
        pos[:, 0] -= np.where(np.abs(det) > 1e-9, (cc * ru - b * rv) / safe, 0.0)
        pos[:, 1] -= np.where(np.abs(det) > 1e-9, (a * rv - b * ru) / safe, 0.0)
    uu, vv = pos[:, 0:1] + du, pos[:, 1:2] + dv
    T = _sample(target.gray, uu, vv).astype(np.float64)
    Tc = T - T.mean(axis=1, keepdims=True)
    ncc = (Tc * Sc).sum(1) / (np.sqrt((Tc ** 2).sum(1) * (Sc ** 2).sum(1)) + 1e-9)
    # the smaller eigenvalue of the gradients' structure tensor per patch pixel: texture in both directions
    tr, dt = a + cc, a * cc - b * b
    lam_min = (tr / 2 - np.sqrt(np.maximum(tr * tr / 4 - dt, 0.0))) / len(gu)
    inside = np.all((uu >= 0) & (uu <= w - 1) & (vv >= 0) & (vv <= h - 1), axis=1)
    ok = (inside & (np.linalg.norm(pos - start, axis=1) <= params.max_shift_px) & (ncc >= params.min_ncc)
          & (lam_min >= params.min_gradient ** 2))
    out[idx[ok]] = pos[ok]
    done[idx[ok]] = True
    return out, done
