"""Joint refinement of a live camera pose over several map keyframes, with its covariance.

After PnP into one keyframe gives an initial `T_map_camera`, the live points (lifted with
the live depth) matched to several keyframes are reprojected into all of them at once and
`T_map_camera` is refined by robust non-linear least squares (scipy `least_squares`,
Cauchy loss) on the stacked, whitened reprojection residuals. Keyframe poses are known
(the map's). The same solve decides the acceptance: a pose counts as confirmed only if
enough keyframes each explain enough of their matches under the joint pose, which replaces
the separate "confirmation by a second keyframe".

Noise model (per correspondence i of keyframe k, whitened before the solve):
    pixel covariance C_i = s_kp^2 I + sigma_z(z_i)^2 g_i g_i^T,  sigma_z(z) = a_z z^2 + b_z,
with g_i = d(projection into k) / d(live depth) — the depth error of the live point moves
its reprojection along the epipolar direction, more so at long range and wide baselines.
Residuals r_i are whitened with C_i^{-1/2} (closed form for identity + rank one), so the
Cauchy scale is in units of sigma.

Where the map keeps depth at the matched keyframe keypoint (`RefineParams.map_depth`), the
correspondence enters as a 3D residual instead, in the keyframe's camera frame:
    e_i = T_kf_live p_i - P_i   (metres; P_i the keyframe keypoint lifted with the map's depth),
    C_i = R S(p_i) R^T + S(P_i),  S(x) = sigma_z(z)^2 u u^T + sigma_lat(z)^2 (I - u u^T),
with u the point's unit ray, sigma_lat(z) = z s_kp / f_kf and R the rotation of T_kf_live:
each correspondence then measures depth twice, so the rotation-translation trade-off that
reprojections into a few nearby keyframes leave loose is pinned by the map's geometry (which
is the map's own: keyframe poses and depth agree by construction).

Covariance (6x6, right perturbation of `T_map_camera`, order (t, rotvec), the convention
of `pipelines.pnp`): the Gauss-Newton covariance of the whitened solve over the inliers,
    Sigma_pts = s2 (J^T J)^-1,  s2 = max(whitened residual variance, 1),
plus a systematic term that more points and more keyframes do not average out — the
sensor's calibration (intrinsics, depth-to-colour extrinsic, depth distortion) and the map's
poses against the live frame. Calibration errors do not cancel in the relative pose between
the live frame and a keyframe: their effect grows with how far the view is turned from the
keyframes (the commutator of a calibration error with the relative rotation; on 7-Scenes the
rotation error correlates with that angle at r = 0.8, about 3-5 % of it), and with how far the
live camera stands from them (depth error and scale grow with range; the map's poses and the
live frame's disagree more between places seen from afar):
    sigma_t(theta, d)^2 = sigma_sys_t^2 + (sigma_sys_t_per_rad theta)^2 + (sigma_sys_t_per_m d)^2
    (same for rotation), Sigma = Sigma_pts + diag(sigma_t^2 I3, sigma_r^2 I3),
with theta = `viewpoint_angle_rad` and d = `keyframe_distance_m` of the joint pose and its
consistent keyframes; then the diagonal is clamped below by `min_sigma_*`. The six
`sigma_sys_*` are fitted by maximum likelihood on a tuning split inside the mapping pass
(bench/accuracy.py, see RefineParams).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from litevloc.base.geometry import backproject_pixels, make_T, rotation_angle, so3_exp
from litevloc.base.params.localization import RefineParams
from litevloc.pipelines.guided_matching import match_by_projection

F64 = NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class KeyframeObservations:
    """Live points matched to one keyframe.

    points_live: (N, 3) metres in the live camera frame (lifted with the live depth).
    pixels: (N, 2) matched keypoints in the keyframe image.
    K: 3x3 keyframe intrinsics; T_map_kf: 4x4 keyframe camera pose in the map.
    depth_kf: (N,) the map's depth (metres, NaN = none) at each matched keyframe keypoint, or
        None when the map keeps none.
    points_kf: (M, 3) metres in the keyframe camera frame: matched keyframe keypoints lifted
        with the map's depth whose live keypoint has no live depth (they enter the solve as
        reprojections into the live image); pixels_live: (M, 2) those live keypoints;
        K_live: 3x3 live intrinsics (needed when M > 0).
    """

    node: int
    points_live: F64
    pixels: F64
    K: F64
    T_map_kf: F64
    depth_kf: F64 | None = None
    points_kf: F64 | None = None
    pixels_live: F64 | None = None
    K_live: F64 | None = None

    @property
    def n_matches(self) -> int:
        """Correspondences of both kinds."""
        return len(self.points_live) + (0 if self.points_kf is None else len(self.points_kf))


@dataclass(frozen=True, eq=False)
class RefineResult:
    """Outcome of the joint solve. `accepted` only if enough keyframes are consistent."""

    accepted: bool
    reason: str
    T_map_camera: F64
    covariance: F64 | None  # 6x6 right perturbation of T_map_camera, (t, rotvec)
    inliers_per_keyframe: dict[int, int] = field(default_factory=dict)
    matches_per_keyframe: dict[int, int] = field(default_factory=dict)
    median_reprojection_px: float = float("nan")
    shift_m: float = 0.0
    shift_deg: float = 0.0
    inlier_rows: _InlierRows | None = field(default=None, repr=False)

    def inlier_points_map(self) -> dict[int, F64]:
        """Per consistent keyframe (by node), its inliers' points (N_k, 3), metres, map frame:
        what the pose rests on (computed on demand: only GL's pooled support check reads them)."""
        return {} if self.inlier_rows is None else self.inlier_rows.points_map()

    @property
    def n_inliers(self) -> int:
        return int(sum(self.inliers_per_keyframe.values()))

    @property
    def consistent_keyframes(self) -> int:
        return len(self.inliers_per_keyframe)


def _camera_points(T_kf_live: F64, pts: F64) -> F64:
    return pts @ T_kf_live[:3, :3].T + T_kf_live[:3, 3]


def _point_jacobian(R: F64, pts: F64) -> F64:
    """(N, 3, 6) derivative of q = R (exp(w) p + dt) + t, the live points `pts` (N, 3) moved into
    a keyframe, w.r.t. a right perturbation (dt, w) of the live pose: dq/d(dt) = R,
    dq/dw = -R [p]x."""
    skew = np.zeros((len(pts), 3, 3))
    skew[:, 0, 1], skew[:, 0, 2] = -pts[:, 2], pts[:, 1]
    skew[:, 1, 0], skew[:, 1, 2] = pts[:, 2], -pts[:, 0]
    skew[:, 2, 0], skew[:, 2, 1] = -pts[:, 1], pts[:, 0]
    return np.concatenate([np.broadcast_to(R, (len(pts), 3, 3)), -R @ skew], axis=2)


def _residuals_and_jacobian(
    T_map_live: F64, obs: KeyframeObservations, pts: F64, px: F64
) -> tuple[F64, F64, F64]:
    """Raw pixel residuals (N, 2), Jacobian (N, 2, 6) w.r.t. a right perturbation of
    T_map_live (t, rotvec) and the derivative of the projection w.r.t. live depth (N, 2)."""
    T_kl = np.linalg.inv(obs.T_map_kf) @ T_map_live
    R = T_kl[:3, :3]
    q = _camera_points(T_kl, pts)
    z = np.where(np.abs(q[:, 2]) < 1e-6, 1e-6, q[:, 2])
    fx, fy, cx, cy = obs.K[0, 0], obs.K[1, 1], obs.K[0, 2], obs.K[1, 2]
    proj = np.stack([fx * q[:, 0] / z + cx, fy * q[:, 1] / z + cy], axis=1)
    r = proj - px
    # d proj / d q, (N, 2, 3)
    dp = np.zeros((len(q), 2, 3))
    dp[:, 0, 0] = fx / z
    dp[:, 0, 2] = -fx * q[:, 0] / z**2
    dp[:, 1, 1] = fy / z
    dp[:, 1, 2] = -fy * q[:, 1] / z**2
    J = dp @ _point_jacobian(R, pts)
    # live depth z_l scales the point along its ray: dp_live/dz_l = p / z_l
    ray = pts / np.where(np.abs(pts[:, 2:3]) < 1e-6, 1e-6, pts[:, 2:3])
    g = np.einsum("nij,nj->ni", dp, ray @ R.T)
    return r, J, g


def _whitener(g: F64, z_live: F64, p: RefineParams) -> F64:
    """(N, 2, 2) W with W C W^T = I for C = s^2 I + sz^2 g g^T."""
    s2 = p.keypoint_sigma_px**2
    sz = p.depth_sigma_a * z_live**2 + p.depth_sigma_b
    a = (sz**2) * np.sum(g * g, axis=1)  # variance added along g
    gn = np.linalg.norm(g, axis=1)
    u = np.where(gn[:, None] > 1e-12, g / np.maximum(gn[:, None], 1e-12), 0.0)
    s = np.sqrt(s2)
    k = 1.0 - s / np.sqrt(s2 + a)  # shrink along u from 1/s to 1/sqrt(s^2 + a)
    eye = np.broadcast_to(np.eye(2), (len(g), 2, 2))
    return np.asarray((eye - k[:, None, None] * u[:, :, None] * u[:, None, :]) / s, dtype=np.float64)


def _point_whitener(T_kl: F64, pts: F64, P_kf: F64, K: F64, p: RefineParams) -> F64:
    """(N, 3, 3) W with W C W^T = I, C the covariance of `T_kl pts - P_kf` (keyframe frame):
    each point's depth noise sigma_z(z) along its own ray and `keypoint_sigma_px` (at the
    keyframe's focal length) across it, the live point's rotated into the keyframe."""

    def cov(rays: F64, z: F64) -> F64:
        u = rays / np.maximum(np.linalg.norm(rays, axis=1, keepdims=True), 1e-12)
        lat = z * p.keypoint_sigma_px / float(K[0, 0])
        rad = p.depth_sigma_a * z**2 + p.depth_sigma_b
        eye = np.broadcast_to(np.eye(3), (len(z), 3, 3))
        return np.asarray((lat**2)[:, None, None] * eye
                          + (rad**2 - lat**2)[:, None, None] * u[:, :, None] * u[:, None, :], dtype=np.float64)

    C = cov(pts @ T_kl[:3, :3].T, pts[:, 2]) + cov(P_kf, P_kf[:, 2])
    L = np.linalg.cholesky(C)
    return np.asarray(np.linalg.inv(L), dtype=np.float64)


class _LiveReprojections:
    """Keyframe points (map depth, keyframe frame) matched to live pixels without live depth:
    residual = projection into the live image - live pixel, whitened like a forward
    reprojection (keypoint noise + the map depth's noise along its ray, `_whitener`)."""

    def __init__(self, ob: KeyframeObservations, P_kf: F64, px_live: F64, T0: F64, p: RefineParams) -> None:
        assert ob.K_live is not None
        self.P_kf, self.px, self.K, self.T_map_kf = P_kf, px_live, ob.K_live, ob.T_map_kf
        _, _, g = self.residuals(T0)
        self.W = _whitener(g, P_kf[:, 2], p)

    def residuals(self, T_map_live: F64) -> tuple[F64, F64, F64]:
        """Pixel residuals (M, 2), Jacobian (M, 2, 6) w.r.t. a right perturbation (t, rotvec) of
        T_map_live and the projection's derivative w.r.t. the map depth (M, 2).
        y = (T exp(d))^-1 X ~ y0 - dt + [y0]x w, so dy/d(dt) = -I, dy/dw = [y0]x."""
        T_lk = np.linalg.inv(T_map_live) @ self.T_map_kf
        y = _camera_points(T_lk, self.P_kf)
        z = np.where(np.abs(y[:, 2]) < 1e-6, 1e-6, y[:, 2])
        fx, fy, cx, cy = self.K[0, 0], self.K[1, 1], self.K[0, 2], self.K[1, 2]
        r = np.stack([fx * y[:, 0] / z + cx, fy * y[:, 1] / z + cy], axis=1) - self.px
        dp = np.zeros((len(y), 2, 3))
        dp[:, 0, 0], dp[:, 0, 2] = fx / z, -fx * y[:, 0] / z**2
        dp[:, 1, 1], dp[:, 1, 2] = fy / z, -fy * y[:, 1] / z**2
        dy = np.zeros((len(y), 3, 6))
        dy[:, :, :3] = -np.eye(3)
        dy[:, 0, 4], dy[:, 0, 5] = -y[:, 2], y[:, 1]
        dy[:, 1, 3], dy[:, 1, 5] = y[:, 2], -y[:, 0]
        dy[:, 2, 3], dy[:, 2, 4] = -y[:, 1], y[:, 0]
        ray = self.P_kf / np.where(np.abs(self.P_kf[:, 2:3]) < 1e-6, 1e-6, self.P_kf[:, 2:3])
        g = np.einsum("nij,nj->ni", dp, ray @ T_lk[:3, :3].T)
        return r, dp @ dy, g

    def whitened(self, T: F64, rows: NDArray[np.bool_]) -> tuple[F64, F64, F64]:
        r, J, _ = self.residuals(T)
        return (np.einsum("nij,nj->ni", self.W[rows], r[rows]).reshape(-1), (self.W[rows] @ J[rows]).reshape(-1, 6),
                np.linalg.norm(r, axis=1))


def _live_reprojections(ob: KeyframeObservations, T0: F64, p: RefineParams) -> _LiveReprojections | None:
    """`ob`'s keyframe points without live depth that lie within `gate_px` of their live pixel
    under the initial pose `T0`, as solve terms; None when there are none."""
    if ob.points_kf is None or ob.pixels_live is None or len(ob.points_kf) == 0:
        return None
    P = np.asarray(ob.points_kf, np.float64).reshape(-1, 3)
    px = np.asarray(ob.pixels_live, np.float64).reshape(-1, 2)
    rev = _LiveReprojections(ob, P, px, T0, p)
    keep = np.linalg.norm(rev.residuals(T0)[0], axis=1) <= p.gate_px
    return _LiveReprojections(ob, P[keep], px[keep], T0, p) if keep.any() else None


class _Terms:
    """One keyframe's correspondences in the solve: pixel residuals (whitened 2-vectors) where
    the map has no depth at the keyframe keypoint, 3D residuals `T_kf_live p_live - P_kf`
    (whitened 3-vectors) where it has (with `RefineParams.map_depth`)."""

    def __init__(self, ob: KeyframeObservations, pts: F64, px: F64, z_kf: F64 | None, T0: F64,
                 p: RefineParams, rev: _LiveReprojections | None = None) -> None:
        self.ob, self.pts, self.px, self.rev = ob, pts, px, rev
        self.z_kf = np.full(len(pts), np.nan) if z_kf is None else np.asarray(z_kf, np.float64)
        _, _, g = _residuals_and_jacobian(T0, ob, pts, px)
        self.W2 = _whitener(g, pts[:, 2], p)
        use3 = (np.isfinite(z_kf) & (z_kf > 0)) if (p.map_depth and z_kf is not None) else np.zeros(len(pts), bool)
        self.use3 = np.asarray(use3, dtype=bool)
        self.P_kf = np.zeros((int(self.use3.sum()), 3))
        self.W3 = np.zeros((0, 3, 3))
        if self.use3.any():
            self.P_kf = backproject_pixels(ob.K, px[self.use3], np.asarray(z_kf, np.float64)[self.use3])
            T_kl = np.linalg.inv(ob.T_map_kf) @ T0
            self.W3 = _point_whitener(T_kl, pts[self.use3], self.P_kf, ob.K, p)

    def whitened(self, T: F64, rows: NDArray[np.bool_] | None = None) -> tuple[F64, F64, F64]:
        """(whitened residuals (M,), whitened Jacobian (M, 6), pixel errors (N,)) at pose T,
        over the correspondences in `rows` (all by default; live points first, then the
        keyframe points reprojected into the live image)."""
        n_rev = 0 if self.rev is None else len(self.rev.P_kf)
        rows = np.ones(len(self.pts) + n_rev, bool) if rows is None else rows
        rows, rows_rev = rows[: len(self.pts)], rows[len(self.pts):]
        r, J, _ = _residuals_and_jacobian(T, self.ob, self.pts, self.px)
        m2 = rows & ~self.use3
        out_r = [np.einsum("nij,nj->ni", self.W2[m2], r[m2]).reshape(-1)]
        out_J = [(self.W2[m2] @ J[m2]).reshape(-1, 6)]
        errors = [np.linalg.norm(r, axis=1)]
        if self.use3.any():
            sel = rows[self.use3]
            T_kl = np.linalg.inv(self.ob.T_map_kf) @ T
            p3 = self.pts[self.use3][sel]
            q = _camera_points(T_kl, p3)
            e = q - self.P_kf[sel]
            dq = _point_jacobian(T_kl[:3, :3], p3)
            W = self.W3[sel]
            out_r.append(np.einsum("nij,nj->ni", W, e).reshape(-1))
            out_J.append((W @ dq).reshape(-1, 6))
        if self.rev is not None:
            rr, rJ, re = self.rev.whitened(T, rows_rev)
            out_r.append(rr)
            out_J.append(rJ)
            errors.append(re)
        return np.concatenate(out_r), np.concatenate(out_J), np.concatenate(errors)

    def map_points(self, T: F64) -> F64:
        """(N, 3) metres, map frame, in `whitened`'s row order: each live point's keyframe keypoint
        lifted with the map's depth where it has some (where it lies whatever the live pose), else
        the live point under the live pose `T`; then the keyframe points reprojected into the live
        image."""
        has = np.isfinite(self.z_kf) & (self.z_kf > 0)
        kf = _camera_points(self.ob.T_map_kf, backproject_pixels(self.ob.K, self.px, np.where(has, self.z_kf, 0.0)))
        out = [np.where(has[:, None], kf, _camera_points(T, self.pts))]
        if self.rev is not None:
            out.append(_camera_points(self.ob.T_map_kf, self.rev.P_kf))
        return np.concatenate(out)


def _perturb(T: F64, d: NDArray[np.floating]) -> F64:
    return T @ make_T(so3_exp(np.asarray(d[3:], dtype=np.float64)), np.asarray(d[:3], dtype=np.float64))


def _solve_terms(observations: list[KeyframeObservations], T0: F64, p: RefineParams) -> list[_Terms]:
    """The keyframes' correspondences within `gate_px` of the initial pose `T0`, as solve terms;
    a keyframe with fewer than `min_keyframe_inliers` of them is left out."""
    used: list[_Terms] = []
    for ob in observations:
        pts = np.asarray(ob.points_live, dtype=np.float64).reshape(-1, 3)
        px = np.asarray(ob.pixels, dtype=np.float64).reshape(-1, 2)
        rev = _live_reprojections(ob, T0, p)
        keep = np.zeros(0, bool)
        if len(pts):
            r, _, _ = _residuals_and_jacobian(T0, ob, pts, px)
            keep = np.linalg.norm(r, axis=1) <= p.gate_px
        if keep.sum() + (0 if rev is None else len(rev.P_kf)) < p.min_keyframe_inliers:
            continue
        z_kf = None if ob.depth_kf is None else np.asarray(ob.depth_kf, np.float64).reshape(-1)[keep]
        used.append(_Terms(ob, pts[keep], px[keep], z_kf, T0, p, rev))
    return used


@dataclass(frozen=True, eq=False)
class _InlierRows:
    """Under the joint pose `T` (4x4 T_map_camera): per consistent keyframe (by node), its solve
    terms and which of their rows (`_Terms.whitened`'s order) are inliers."""

    T: F64
    terms: dict[int, _Terms]
    rows: dict[int, NDArray[np.bool_]]

    def points_map(self) -> dict[int, F64]:
        """Per keyframe, its inliers' map-frame points (N_k, 3), metres (see `_Terms.map_points`)."""
        return {k: self.terms[k].map_points(self.T)[ok] for k, ok in self.rows.items()}


@dataclass(frozen=True)
class _Consistent:
    """Under a joint pose: the inliers (within `inlier_px`) of each keyframe with at least
    `min_keyframe_inliers` of them, by node; their pixel errors; their 6x6 information matrices
    (whitened Gauss-Newton, scaled by the residual variance where it exceeds 1); which rows they are."""

    inliers: dict[int, int]
    errors: list[F64]
    info: list[F64]
    rows: _InlierRows


def _consistent_keyframes(used: list[_Terms], T: F64, p: RefineParams) -> _Consistent:
    """The keyframes of `used` consistent with the joint pose `T` (see `_Consistent`)."""
    inl: dict[int, int] = {}
    errs: list[F64] = []
    info: list[F64] = []
    rows = _InlierRows(T, {}, {})
    for t in used:
        _, _, e = t.whitened(T)
        ok = e <= p.inlier_px
        if ok.sum() < p.min_keyframe_inliers:
            continue
        inl[t.ob.node] = int(ok.sum())
        errs.append(e[ok])
        rows.terms[t.ob.node], rows.rows[t.ob.node] = t, ok
        rw, Jw, _ = t.whitened(T, ok)
        s2 = max(float(rw @ rw) / max(len(rw) - 6, 1), 1.0)
        info.append(Jw.T @ Jw / s2)
    return _Consistent(inl, errs, info, rows)


def refine_pose(
    T_map_camera_init: NDArray[np.floating], observations: list[KeyframeObservations], params: RefineParams
) -> RefineResult:
    """Refine `T_map_camera` over the matches to several keyframes and decide acceptance.

    Args:
        T_map_camera_init: 4x4 initial pose (e.g. PnP into the first keyframe).
        observations: per keyframe, live points and their matched keyframe pixels
            (the first is the keyframe the initial pose came from).
        params: see `RefineParams`.
    Returns:
        RefineResult with the refined pose, its 6x6 covariance, the inliers of every
        consistent keyframe and why it was (not) accepted.
    """
    T0 = np.asarray(T_map_camera_init, dtype=np.float64)
    p = params
    used = _solve_terms(observations, T0, p)
    matches = {ob.node: ob.n_matches for ob in observations}
    if not used:  # (one consistent keyframe is still solved: its pose can be a provisional GL vote)
        return RefineResult(False, f"no keyframe consistent with the initial pose (< {p.min_keyframes})",
                            T0, None, {}, matches)

    last: dict[bytes, tuple[F64, F64]] = {}

    def evaluate(d: F64) -> tuple[F64, F64]:
        """Stacked whitened residuals and Jacobian at T0 exp(d), once per step (the solver asks
        for both at the same point)."""
        key = np.asarray(d, np.float64).tobytes()
        if key not in last:
            T = _perturb(T0, d)
            parts = [t.whitened(T) for t in used]
            last.clear()
            last[key] = (np.concatenate([r for r, _, _ in parts]), np.concatenate([J for _, J, _ in parts]))
        return last[key]

    def fun(d: F64) -> F64:
        return evaluate(d)[0]

    def jac(d: F64) -> F64:
        # d/dd of T0 exp(d) ~ right perturbation at T for small steps (exact at d = 0)
        return evaluate(d)[1]

    sol = least_squares(fun, np.zeros(6), jac=jac, loss=p.loss, f_scale=p.loss_scale, method="trf",
                        max_nfev=p.max_nfev, x_scale="jac")
    T = _perturb(T0, sol.x)
    shift_m = float(np.linalg.norm(T[:3, 3] - T0[:3, 3]))
    dR = T0[:3, :3].T @ T[:3, :3]
    shift_deg = float(np.degrees(np.arccos(np.clip((np.trace(dR) - 1) / 2, -1, 1))))

    cons = _consistent_keyframes(used, T, p)
    inl, errs, info = cons.inliers, cons.errors, cons.info
    med = float(np.median(np.concatenate(errs))) if errs else float("nan")
    kfs = np.stack([t.ob.T_map_kf for t in used if t.ob.node in inl]) if inl else np.zeros((0, 4, 4))
    cov = joint_covariance(info, p, viewpoint_angle_rad(T, kfs), keyframe_distance_m(T, kfs)) if info else None
    if len(inl) < p.min_keyframes:
        reason = f"only {len(inl)} keyframe(s) consistent with the joint pose (< {p.min_keyframes})"
    elif shift_m > p.max_shift_m or shift_deg > p.max_shift_deg:
        reason = f"joint pose moved {shift_m:.2f} m / {shift_deg:.1f} deg from the initial pose"
    else:
        reason = "ok"
    return RefineResult(reason == "ok", reason, T, cov, inl, matches, med, shift_m, shift_deg, cons.rows)


def viewpoint_angle_rad(T_map_camera: NDArray[np.floating], T_map_keyframes: NDArray[np.floating]) -> float:
    """Mean rotation angle (radians) between a camera pose (4x4) and keyframe poses (K, 4, 4):
    how far the live view is turned from the keyframes that support it."""
    R = np.asarray(T_map_camera, dtype=np.float64)[:3, :3]
    Rk = np.asarray(T_map_keyframes, dtype=np.float64).reshape(-1, 4, 4)[:, :3, :3]
    return float(np.mean([rotation_angle(r.T @ R) for r in Rk])) if len(Rk) else 0.0


def keyframe_distance_m(T_map_camera: NDArray[np.floating], T_map_keyframes: NDArray[np.floating]) -> float:
    """Mean distance (metres) between a camera's position (4x4 pose) and the keyframes' (K, 4, 4);
    0 without keyframes."""
    c = np.asarray(T_map_camera, dtype=np.float64)[:3, 3]
    k = np.asarray(T_map_keyframes, dtype=np.float64).reshape(-1, 4, 4)[:, :3, 3]
    return float(np.mean(np.linalg.norm(k - c, axis=1))) if len(k) else 0.0


def systematic_variances(params: RefineParams, view_angle_rad: float, distance_m: float) -> tuple[float, float]:
    """Per-axis variance of the systematic terms (see the module docstring): position (m^2) and
    rotation (rad^2) at a view angle (radians) and distance to the keyframes (metres)."""
    var_t = (params.sigma_sys_t_m**2 + (params.sigma_sys_t_per_rad * view_angle_rad) ** 2
             + (params.sigma_sys_t_per_m * distance_m) ** 2)
    var_r = (np.radians(params.sigma_sys_r_deg) ** 2 + (params.sigma_sys_r_per_rad * view_angle_rad) ** 2
             + np.radians(params.sigma_sys_r_deg_per_m * distance_m) ** 2)
    return float(var_t), float(var_r)


def joint_covariance(information: list[F64], params: RefineParams, view_angle_rad: float = 0.0,
                     distance_m: float = 0.0) -> F64:
    """6x6 covariance from per-keyframe information matrices (see the module docstring);
    `view_angle_rad` / `distance_m`: `viewpoint_angle_rad` / `keyframe_distance_m` of the pose
    and its consistent keyframes."""
    total = np.sum(information, axis=0) if information else np.zeros((6, 6))
    try:
        cov = np.linalg.inv(total)
    except np.linalg.LinAlgError:
        cov = np.diag([1e2] * 6)
    cov = 0.5 * (cov + cov.T)
    var_t, var_r = systematic_variances(params, view_angle_rad, distance_m)
    cov += np.diag([var_t] * 3 + [var_r] * 3)
    floor = np.array([params.min_sigma_t_m] * 3 + [np.radians(params.min_sigma_r_deg)] * 3) ** 2
    cov[np.diag_indices(6)] = np.maximum(np.diag(cov), floor)
    return cov


def guided_matches(
    points_live: NDArray[np.floating], desc_live: NDArray[Any], T_map_live: NDArray[np.floating],
    kf_keypoints: NDArray[np.floating], kf_desc: NDArray[Any], K_kf: NDArray[np.floating],
    T_map_kf: NDArray[np.floating], params: RefineParams, global_mutual: bool | None = None,
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """`pipelines.guided_matching.match_by_projection` with the refinement's radius,
    similarity threshold and global-mutual rule (see `RefineParams`; `global_mutual` given: that rule instead)."""
    mutual = params.guided_global_mutual if global_mutual is None else global_mutual
    return match_by_projection(points_live, desc_live, T_map_live, kf_keypoints, kf_desc, K_kf, T_map_kf,
                               params.guided_radius_px, params.guided_min_similarity, mutual)
