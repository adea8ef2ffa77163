"""Metric pose from 3D-2D matches: OpenCV PnP + RANSAC, LM refinement, acceptance gates.

Used by covisibility verification (map building) and by local/global localization:
points lifted from one camera's depth (frame `source`) are matched to pixels of another
camera (frame `target`); the result `T_target_source` maps source-frame points into the
target camera frame. RANSAC is seeded (`cv2.setRNGSeed`) so results are reproducible.

Covariance estimate (documented model, used as the VLoc measurement noise):
    Sigma = s^2 * (J^T J)^-1 over the inliers, s^2 = max(sum(r^2) / (2n - 6), 0.25 px^2),
with J the 2n x 6 Jacobian of the inlier reprojections w.r.t. a right (source-frame)
perturbation `T_target_source @ exp(d)`, d = (tx, ty, tz, rx, ry, rz) — translation first,
rotation vector second. When the source is the live camera this is the covariance of
`T_map_camera` perturbed in the camera frame. Diagonal entries are clamped below by
`min_sigma_*` so that a lucky fit is never over-confident.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from enum import Enum
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from litevloc.base.geometry import invert, make_T, project, so3_exp
from litevloc.base.params.localization import PnpParams

_FLAGS = {"p3p": cv2.SOLVEPNP_P3P, "ap3p": cv2.SOLVEPNP_AP3P, "sqpnp": cv2.SOLVEPNP_SQPNP, "epnp": cv2.SOLVEPNP_EPNP}


class Refusal(Enum):
    """Why a candidate pose was refused, by kind (the result's reason says it in words, with numbers)."""

    NONE = "none"  # accepted
    MATCHES = "matches"  # the matcher found fewer matches than PnP could accept (PnP not run)
    DEPTH = "depth"  # too few matches with depth for PnP
    NO_POSE = "no pose"  # PnP / RANSAC found no pose
    INLIERS = "inliers"  # fewer inliers than the floor
    INLIER_RATIO = "inlier ratio"  # too small a share of the matches are inliers
    REPROJECTION = "reprojection"  # median reprojection error over the gate
    DISTANCE = "distance"  # the pose lies implausibly far from its reference keyframe
    LATER = "later check"  # PnP passed; a later check refused it (floor plane, prior gate, second keyframe)


@dataclass(frozen=True, eq=False)
class PnpResult:
    """Outcome of one PnP attempt; `accepted` only if every gate passed."""

    accepted: bool
    reason: str
    T_target_source: NDArray[np.float64] | None = None
    inliers: NDArray[np.intp] = field(default_factory=lambda: np.zeros(0, dtype=np.intp))
    n_matches: int = 0
    median_reprojection_px: float = float("nan")
    covariance: NDArray[np.float64] | None = None  # 6x6, right perturbation of T_target_source, (t, rotvec)
    # RANSAC's consensus set (match indices, sorted), before the refined pose re-scores `inliers`
    ransac_inliers: NDArray[np.intp] = field(default_factory=lambda: np.zeros(0, dtype=np.intp))
    refusal: Refusal = Refusal.NONE  # which gate refused it (NONE when accepted)

    @property
    def n_inliers(self) -> int:
        """Matches within `reprojection_px` of the refined pose."""
        return len(self.inliers)

    @property
    def n_ransac_inliers(self) -> int:
        """Size of RANSAC's consensus set (a looser count than `n_inliers` when the refinement
        moves the pose)."""
        return len(self.ransac_inliers)

    @property
    def inlier_ratio(self) -> float:
        return self.n_inliers / self.n_matches if self.n_matches else 0.0


def _ransac(
    obj: NDArray[np.float64], img: NDArray[np.float64], K: NDArray[np.float64], p: PnpParams
) -> tuple[bool, Any, Any, Any]:
    cv2.setRNGSeed(p.seed)
    if p.method == "usac_magsac":
        up = cv2.UsacParams()
        up.sampler = cv2.SAMPLING_UNIFORM
        up.score = cv2.SCORE_METHOD_MAGSAC
        up.threshold = p.reprojection_px
        up.confidence = p.confidence
        up.maxIterations = p.iterations
        up.loMethod = cv2.LOCAL_OPTIM_SIGMA
        up.loIterations = 10
        up.loSampleSize = 20
        up.randomGeneratorState = p.seed
        ok, _, rvec, tvec, inl = cv2.solvePnPRansac(obj, img, K.copy(), None, params=up)
        return ok, rvec, tvec, inl
    ok, rvec, tvec, inl = cv2.solvePnPRansac(
        obj, img, K, None, iterationsCount=p.iterations, reprojectionError=p.reprojection_px,
        confidence=p.confidence, flags=_FLAGS[p.method],
    )
    return ok, rvec, tvec, inl


def pose_covariance(
    points_source: NDArray[np.float64], pixels: NDArray[np.float64], K: NDArray[np.float64],
    T_target_source: NDArray[np.float64], p: PnpParams,
) -> NDArray[np.float64]:
    """6x6 covariance of a right perturbation of T_target_source, order (t, rotvec)."""
    n = len(points_source)

    def residuals(T_ts: NDArray[np.float64]) -> NDArray[np.float64]:
        pc = points_source @ T_ts[:3, :3].T + T_ts[:3, 3]
        return (project(K, pc) - pixels).reshape(-1)

    r0 = residuals(T_target_source)
    J = np.zeros((2 * n, 6))
    eps = 1e-6
    for k in range(6):
        d = np.zeros(6)
        d[k] = eps
        J[:, k] = (residuals(T_target_source @ make_T(so3_exp(d[3:]), d[:3])) - r0) / eps
    dof = max(2 * n - 6, 1)
    s2 = max(float(r0 @ r0) / dof, 0.25)  # at least (0.5 px)^2: keypoints are not exact
    try:
        cov = s2 * np.linalg.inv(J.T @ J)
    except np.linalg.LinAlgError:
        cov = np.diag([1e2] * 6)
    floor = np.array([p.min_sigma_trans_m] * 3 + [p.min_sigma_rot_rad] * 3) ** 2
    cov = 0.5 * (cov + cov.T)
    cov[np.diag_indices(6)] = np.maximum(np.diag(cov), floor)
    return cov


PnpFits = dict[tuple[bytes, PnpParams], PnpResult]  # RANSAC fits before the gates, by problem (see `solve_pnp`)


def solve_pnp(
    points_source: NDArray[np.floating], pixels_target: NDArray[np.floating], K_target: NDArray[np.floating],
    params: PnpParams = PnpParams(), fits: PnpFits | None = None,
) -> PnpResult:
    """Pose of the target camera from source-frame 3D points and their target pixels.

    Args:
        points_source: (N, 3) metres in the source frame (e.g. the live camera, from depth).
        pixels_target: (N, 2) pixels in the target image (same order).
        K_target: 3x3 intrinsics of the target image.
        fits: where given, the fit (RANSAC, refinement, inliers, covariance) of a problem seen
            before with the same points, pixels, intrinsics and fitting parameters is reused;
            only the acceptance gates (`min_inliers`, ratio, median error) are applied again.
    Returns:
        PnpResult; `T_target_source` is set whenever RANSAC found a model, `accepted` only
        if inlier count, inlier ratio and median reprojection error pass the gates.
    """
    obj = np.ascontiguousarray(points_source, dtype=np.float64).reshape(-1, 3)
    img = np.ascontiguousarray(pixels_target, dtype=np.float64).reshape(-1, 2)
    K = np.asarray(K_target, dtype=np.float64)
    n = len(obj)
    if len(img) != n:
        raise ValueError(f"{n} points but {len(img)} pixels")
    finite = np.all(np.isfinite(obj), axis=1) & np.all(np.isfinite(img), axis=1)
    if not np.all(finite):
        raise ValueError("points and pixels must be finite (filter invalid depth first)")
    if n < max(p_min := params.min_inliers, 4):
        return PnpResult(False, f"too few matches with depth ({n} < {p_min})", n_matches=n, refusal=Refusal.DEPTH)
    if fits is None:
        return _gated(_fit(obj, img, K, params), params)
    # the gates do not enter the fit: problems that differ only in them share it
    key = (obj.tobytes() + img.tobytes() + K.tobytes(),
           replace(params, min_inliers=4, min_inlier_ratio=0.0, max_median_reprojection_px=float("inf")))
    if key not in fits:
        fits[key] = _fit(obj, img, K, params)
    return _gated(fits[key], params)


def _fit(obj: NDArray[np.float64], img: NDArray[np.float64], K: NDArray[np.float64], params: PnpParams) -> PnpResult:
    """RANSAC + refinement + re-scored inliers and covariance; accepted (no gate applied yet)
    when RANSAC found a pose."""
    n = len(obj)
    try:
        ok, rvec, tvec, inl = _ransac(obj, img, K, params)
    except cv2.error as exc:
        return PnpResult(False, f"PnP failed: {exc.err}", n_matches=n, refusal=Refusal.NO_POSE)
    if not ok or inl is None or len(inl) < 4:
        consensus = np.zeros(0, np.intp) if inl is None else np.sort(np.asarray(inl, dtype=np.intp).reshape(-1))
        return PnpResult(False, "RANSAC found no pose", n_matches=n, ransac_inliers=consensus,
                         refusal=Refusal.NO_POSE)
    idx = np.sort(np.asarray(inl, dtype=np.intp).reshape(-1))
    if params.refine_lm:
        rvec, tvec = cv2.solvePnPRefineLM(obj[idx], img[idx], K, None, rvec, tvec)
    R, _ = cv2.Rodrigues(np.asarray(rvec, dtype=np.float64))
    T = make_T(np.asarray(R), np.asarray(tvec, dtype=np.float64).reshape(3))
    pc = obj @ R.T + T[:3, 3]
    with np.errstate(invalid="ignore", divide="ignore"):
        err = np.linalg.norm(project(K, pc) - img, axis=1)
    err[pc[:, 2] <= 0] = np.inf
    inliers = np.nonzero(err <= params.reprojection_px)[0]  # re-scored with the refined pose
    med = float(np.median(err[inliers])) if len(inliers) else float("inf")
    cov = pose_covariance(obj[inliers], img[inliers], K, T, params) if len(inliers) >= 6 else None
    return PnpResult(True, "ok", T, inliers, n, med, cov, idx)


def _gated(fit: PnpResult, params: PnpParams) -> PnpResult:
    """`fit` through the acceptance gates of `params` (inlier count, ratio, median error)."""
    if not fit.accepted:
        return fit
    k, n, med = fit.n_inliers, fit.n_matches, fit.median_reprojection_px
    ratio = k / n
    refusal, reason = Refusal.NONE, "ok"
    if k < params.min_inliers:
        refusal, reason = Refusal.INLIERS, f"too few inliers ({k} < {params.min_inliers})"
    elif ratio < params.min_inlier_ratio:
        refusal, reason = Refusal.INLIER_RATIO, f"inlier ratio too low ({ratio:.2f} < {params.min_inlier_ratio})"
    elif med > params.max_median_reprojection_px:
        refusal, reason = (Refusal.REPROJECTION,
                           f"median reprojection error too high ({med:.2f} px > {params.max_median_reprojection_px})")
    return replace(fit, accepted=refusal is Refusal.NONE, reason=reason, refusal=refusal)


def inverse_result(res: PnpResult) -> PnpResult:
    """The same PnP result for the inverse pose: `T_source_target`, its covariance that of a
    right perturbation of the inverse ((A exp(d))^-1 = A^-1 exp(-Ad_A d), so Sigma' =
    Ad_A Sigma Ad_A^T with Ad_A = [[R, [t]x R], [0, R]] in (t, rotvec) order). Gates, inliers
    and errors are unchanged."""
    if res.T_target_source is None:
        return res
    A = np.asarray(res.T_target_source, np.float64)
    cov = None
    if res.covariance is not None:
        R, t = A[:3, :3], A[:3, 3]
        tx = np.array([[0.0, -t[2], t[1]], [t[2], 0.0, -t[0]], [-t[1], t[0], 0.0]])
        ad = np.block([[R, tx @ R], [np.zeros((3, 3)), R]])
        cov = ad @ res.covariance @ ad.T
    return PnpResult(res.accepted, res.reason, invert(A), res.inliers, res.n_matches, res.median_reprojection_px, cov,
                     res.ransac_inliers, res.refusal)
