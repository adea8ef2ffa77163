"""Joint multi-keyframe refinement: accuracy gain, robustness, acceptance, covariance."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.stats import chi2

from litevloc.base.geometry import make_T, so3_exp, so3_log
from litevloc.base.params.localization import RefineParams
from litevloc.pipelines.localization.refine import (
    KeyframeObservations,
    RefineResult,
    joint_covariance,
    keyframe_distance_m,
    refine_pose,
    viewpoint_angle_rad,
)

K = np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]])
T_MAP_LIVE = make_T(so3_exp(np.array([0.05, -0.3, 0.02])), np.array([0.4, -0.1, 0.2]))
# keyframes around the live camera, looking roughly the same way (camera z forward)
KF_POSES = [T_MAP_LIVE @ make_T(so3_exp(np.array(w)), np.array(t)) for w, t in (
    ([0.0, 0.1, 0.0], [-0.3, 0.0, -0.2]), ([0.02, -0.15, 0.0], [0.35, 0.05, 0.1]),
    ([0.0, 0.05, 0.03], [0.0, -0.2, -0.4]))]


def _observations(rng: np.random.Generator, n: int, px_sigma: float, outliers: float = 0.0,
                  T_truth: np.ndarray = T_MAP_LIVE) -> list[KeyframeObservations]:
    """Live points in front of the camera, seen (projected with noise) by each keyframe."""
    obs = []
    for k, T_map_kf in enumerate(KF_POSES):
        uv = rng.uniform([20, 20], [620, 460], size=(n, 2))
        z = rng.uniform(1.0, 3.5, size=n)
        pts = np.column_stack([(uv[:, 0] - 320) / 500 * z, (uv[:, 1] - 240) / 500 * z, z])
        T_kl = np.linalg.inv(T_map_kf) @ T_truth
        q = pts @ T_kl[:3, :3].T + T_kl[:3, 3]
        px = q[:, :2] / q[:, 2:3] * 500 + [320, 240] + rng.normal(0, px_sigma, size=(n, 2))
        bad = rng.random(n) < outliers
        px[bad] = rng.uniform([0, 0], [640, 480], size=(int(bad.sum()), 2))
        obs.append(KeyframeObservations(k, pts, px, K, T_map_kf))
    return obs


def _err(T: np.ndarray, T_gt: np.ndarray = T_MAP_LIVE) -> tuple[np.ndarray, np.ndarray]:
    E = np.linalg.inv(T) @ T_gt
    return E[:3, 3], so3_log(E[:3, :3])


def _nees(res: RefineResult) -> tuple[float, float]:
    """Squared Mahalanobis distances (NEES) of an accepted solve's position and rotation errors
    under its own covariance blocks: chi-square with 3 dof when the covariance is right."""
    assert res.accepted and res.covariance is not None, res.reason
    dt, dr = _err(res.T_map_camera)
    return (float(dt @ np.linalg.solve(res.covariance[:3, :3], dt)),
            float(dr @ np.linalg.solve(res.covariance[3:, 3:], dr)))


def _assert_calibrated(nees: list[tuple[float, float]]) -> None:
    """The errors fit their covariance: ~95 % inside the 95 % ellipsoid (binomial, 3 sigma) AND
    the mean NEES ~3 (3 dof; 3 sigma of the mean of n chi-square(3) draws is 3 * sqrt(6 / n)): a
    covariance too wide (all inside, NEES far below 3) fails as surely as one too narrow."""
    e = np.asarray(nees)
    n = len(e)
    inside = np.mean(e <= chi2.ppf(0.95, 3), axis=0)
    tol = 3 * np.sqrt(0.95 * 0.05 / n)
    assert np.all(inside >= 0.95 - tol), inside  # position, rotation
    band = 3 * np.sqrt(6 / n)
    assert np.all(np.abs(e.mean(axis=0) - 3) <= band), (e.mean(axis=0), band)


def test_refines_a_perturbed_pose_through_outliers() -> None:
    rng = np.random.default_rng(0)
    obs = _observations(rng, 150, 0.7, outliers=0.3)
    T0 = T_MAP_LIVE @ make_T(so3_exp(np.radians([0.6, -0.4, 0.3])), np.array([0.02, -0.015, 0.01]))
    res = refine_pose(T0, obs, RefineParams(gate_px=40.0))
    assert res.accepted, res.reason
    dt, dr = _err(res.T_map_camera)
    dt0, _ = _err(T0)
    assert np.linalg.norm(dt) < 0.1 * np.linalg.norm(dt0) and np.linalg.norm(dt) < 3e-3
    assert np.degrees(np.linalg.norm(dr)) < 0.1
    assert res.consistent_keyframes == 3
    assert all(v > 80 for v in res.inliers_per_keyframe.values())  # ~70 % of 150 are inliers
    assert res.covariance is not None and res.covariance.shape == (6, 6)
    assert np.all(np.linalg.eigvalsh(res.covariance) > 0)


def test_inconsistent_keyframe_is_left_out_and_can_reject() -> None:
    rng = np.random.default_rng(1)
    obs = _observations(rng, 120, 0.5)
    # keyframe 2's matches all belong to another place: uniformly random pixels
    obs[2] = replace(obs[2], pixels=rng.uniform([0, 0], [640, 480], size=(120, 2)))
    res = refine_pose(T_MAP_LIVE, obs, RefineParams(min_keyframes=2))
    assert res.accepted and set(res.inliers_per_keyframe) == {0, 1}
    # with only the first keyframe and a bad second one, two consistent keyframes cannot be found
    res = refine_pose(T_MAP_LIVE, [obs[0], obs[2]], RefineParams(min_keyframes=2))
    assert not res.accepted and "consistent" in res.reason
    assert refine_pose(T_MAP_LIVE, [obs[0], obs[2]], RefineParams(min_keyframes=1)).accepted


def test_wrong_initial_pose_is_not_confirmed() -> None:
    """A pose off by 40 cm explains no keyframe: rejected, never a guess."""
    rng = np.random.default_rng(2)
    obs = _observations(rng, 100, 0.5)
    T_bad = T_MAP_LIVE @ make_T(np.eye(3), np.array([0.4, 0.0, 0.0]))
    res = refine_pose(T_bad, obs, RefineParams())
    assert not res.accepted


def test_covariance_is_calibrated_without_keyframe_error() -> None:
    """Monte Carlo with pixel noise = the model's sigma and no keyframe or depth error: the
    95 % ellipsoid holds ~95 % of the errors and the mean NEES is ~3 (the keyframe term and floors
    switched off)."""
    p = RefineParams(sigma_sys_t_m=0.0, sigma_sys_r_deg=0.0, min_sigma_t_m=0.0, min_sigma_r_deg=0.0,
                     sigma_sys_t_per_rad=0.0, sigma_sys_r_per_rad=0.0,
                     sigma_sys_t_per_m=0.0, sigma_sys_r_deg_per_m=0.0,
                     depth_sigma_a=0.0, depth_sigma_b=0.0, keypoint_sigma_px=1.0)
    rng = np.random.default_rng(3)
    _assert_calibrated([_nees(refine_pose(T_MAP_LIVE, _observations(rng, 40, 1.0), p)) for _ in range(60)])


def test_systematic_term_widens_the_covariance() -> None:
    rng = np.random.default_rng(4)
    obs = _observations(rng, 200, 0.5)
    tight = refine_pose(T_MAP_LIVE, obs, RefineParams(sigma_sys_t_m=0.0, sigma_sys_r_deg=0.0, min_sigma_t_m=0.0,
                                                      min_sigma_r_deg=0.0))
    wide = refine_pose(T_MAP_LIVE, obs, RefineParams(sigma_sys_t_m=0.01, sigma_sys_r_deg=0.0, min_sigma_t_m=0.0,
                                                     min_sigma_r_deg=0.0))
    assert tight.covariance is not None and wide.covariance is not None
    # the systematic 1 cm per axis is added whatever the number of points
    assert np.allclose(np.diag(wide.covariance)[:3] - np.diag(tight.covariance)[:3], 0.01**2)
    assert np.all(np.diag(wide.covariance)[:3] > np.diag(tight.covariance)[:3])


def test_viewpoint_angle_is_the_mean_rotation_to_the_keyframes() -> None:
    T = make_T(so3_exp(np.array([0.0, 0.4, 0.0])), np.array([1.0, 2.0, 0.0]))
    kfs = np.stack([T @ make_T(so3_exp(np.array([0.0, 0.0, 0.3])), np.array([0.5, 0.0, 0.0])),
                    T @ make_T(so3_exp(np.array([0.1, 0.0, 0.0])), np.zeros(3))])
    assert viewpoint_angle_rad(T, kfs) == pytest.approx(0.2, abs=1e-9)
    assert viewpoint_angle_rad(T, kfs[:0]) == 0.0


@pytest.mark.parametrize("measure", ["angle", "distance"])
def test_systematic_term_grows_with_the_viewpoint_angle_and_the_distance(measure: str) -> None:
    """sigma_sys^2 = sigma0^2 + (k_rad theta)^2 + (k_m d)^2, theta / d the angle to / mean distance
    from the consistent keyframes; here each growth term alone."""
    rng = np.random.default_rng(6)
    obs = _observations(rng, 200, 0.5)
    base = RefineParams(sigma_sys_t_m=0.0, sigma_sys_r_deg=0.0, min_sigma_t_m=0.0, min_sigma_r_deg=0.0,
                        sigma_sys_t_per_rad=0.0, sigma_sys_r_per_rad=0.0, sigma_sys_t_per_m=0.0,
                        sigma_sys_r_deg_per_m=0.0)
    if measure == "angle":
        k_t, k_r, grow = 0.1, 0.05, {"sigma_sys_t_per_rad": 0.1, "sigma_sys_r_per_rad": 0.05}
        of = viewpoint_angle_rad
    else:  # rotation per metre is given in degrees
        k_t, k_r, grow = 0.02, np.radians(1.0), {"sigma_sys_t_per_m": 0.02, "sigma_sys_r_deg_per_m": 1.0}
        of = keyframe_distance_m
    flat = refine_pose(T_MAP_LIVE, obs, base)
    grown = refine_pose(T_MAP_LIVE, obs, replace(base, **grow))
    assert flat.covariance is not None and grown.covariance is not None
    x = of(grown.T_map_camera, np.stack([kf for kf in KF_POSES]))
    assert x > 0.05
    added = np.diag(grown.covariance) - np.diag(flat.covariance)
    assert np.allclose(added[:3], (k_t * x) ** 2, rtol=1e-6)
    assert np.allclose(added[3:], (k_r * x) ** 2, rtol=1e-6)
    # the keyframes looking the same way from the same place: nothing is added
    assert np.allclose(joint_covariance([np.eye(6)], replace(base, **grow), 0.0, 0.0),
                       joint_covariance([np.eye(6)], base, 0.0, 0.0))


def test_keyframe_distance_is_the_mean_distance_to_the_keyframes() -> None:
    T = make_T(so3_exp(np.array([0.0, 0.4, 0.0])), np.array([1.0, 2.0, 0.0]))
    kfs = np.stack([make_T(np.eye(3), np.array([1.0, 2.0, 0.5])), make_T(so3_exp(np.array([0.0, 0.0, 1.0])),
                                                                       np.array([1.0, 0.5, 0.0]))])
    assert keyframe_distance_m(T, kfs) == pytest.approx(1.0, abs=1e-12)
    assert keyframe_distance_m(T, kfs[:0]) == 0.0


def test_depth_noise_down_weights_far_points() -> None:
    """With range-dependent depth noise the solve still converges and the covariance grows."""
    rng = np.random.default_rng(5)
    obs = _observations(rng, 150, 0.5)
    base = RefineParams(sigma_sys_t_m=0.0, sigma_sys_r_deg=0.0, min_sigma_t_m=0.0, min_sigma_r_deg=0.0)
    a = refine_pose(T_MAP_LIVE, obs, replace(base, depth_sigma_a=0.0, depth_sigma_b=0.0))
    b = refine_pose(T_MAP_LIVE, obs, replace(base, depth_sigma_a=0.01, depth_sigma_b=0.0))
    assert a.accepted and b.accepted and a.covariance is not None and b.covariance is not None
    assert np.trace(b.covariance[:3, :3]) > np.trace(a.covariance[:3, :3])


@pytest.mark.parametrize("kw", [{"max_keyframes": 0}, {"min_keyframes": 4}, {"loss": "l2"}, {"inlier_px": 0},
                                {"gate_px": 1.0}, {"sigma_sys_t_m": -1.0}, {"loss_scale": 0},
                                {"sigma_sys_r_per_rad": -0.1}, {"sigma_sys_t_per_m": -0.01}])
def test_bad_params_are_errors(kw: dict) -> None:
    with pytest.raises(ValueError):
        RefineParams(**kw)


def test_guided_matches_recover_true_pairs() -> None:
    from litevloc.pipelines.localization.refine import guided_matches

    rng = np.random.default_rng(6)
    obs = _observations(rng, 200, 0.5)[1]
    desc = rng.normal(size=(200, 32)).astype(np.float32)
    desc /= np.linalg.norm(desc, axis=1, keepdims=True)
    # keyframe: the true projections (shuffled) with slightly noisy descriptors, plus 100 distractors
    perm = rng.permutation(200)
    kp = np.vstack([obs.pixels[perm], rng.uniform([0, 0], [640, 480], size=(100, 2))])
    kd = np.vstack([desc[perm] + 0.1 * rng.normal(size=(200, 32)), rng.normal(size=(100, 32))]).astype(np.float32)
    pts = obs.points_live.copy()
    pts[:10] = np.nan  # no depth: never matched
    T0 = T_MAP_LIVE @ make_T(so3_exp(np.radians([0.2, -0.1, 0.1])), np.array([0.005, 0.0, -0.005]))
    il, ik = guided_matches(pts, desc, T0, kp, kd, K, obs.T_map_kf, RefineParams(guided_min_similarity=0.7))
    assert len(il) > 150 and len(set(il)) == len(il) and len(set(ik)) == len(ik)
    assert np.all(il >= 10)
    correct = np.mean(ik < 200) and np.mean(perm[ik[ik < 200]] == il[ik < 200])
    assert correct > 0.98
    # a pose 0.5 m off finds (almost) nothing
    far = T_MAP_LIVE @ make_T(np.eye(3), np.array([0.5, 0.0, 0.0]))
    il, _ = guided_matches(pts, desc, far, kp, kd, K, obs.T_map_kf, RefineParams(guided_min_similarity=0.7))
    assert len(il) < 10


def test_guided_matches_without_the_global_mutual_rule_keep_pairs_a_repeated_texture_hides() -> None:
    """A keyframe where each true keypoint's texture repeats elsewhere (an exact copy of its
    descriptor far away): the global-mutual rule drops the true pairs, `global_mutual=False`
    (LL's guided PnP matches, `local_search.guided_global_mutual`) keeps the best pair in reach."""
    from litevloc.pipelines.localization.refine import guided_matches

    rng = np.random.default_rng(7)
    obs = _observations(rng, 200, 0.5)[1]
    desc = rng.normal(size=(200, 32)).astype(np.float32)
    desc /= np.linalg.norm(desc, axis=1, keepdims=True)
    copies = (obs.pixels + np.array([320.0, 0.0])) % np.array([640.0, 480.0])  # 320 px away from each true one
    kp = np.vstack([obs.pixels, copies])
    kd = np.vstack([desc + 0.1 * rng.normal(size=(200, 32)), desc]).astype(np.float32)
    params = RefineParams(guided_min_similarity=0.7)
    il, _ = guided_matches(obs.points_live, desc, T_MAP_LIVE, kp, kd, K, obs.T_map_kf, params)
    assert len(il) < 10  # the default (joint refinement's extra keyframes): the copies win globally
    il, ik = guided_matches(obs.points_live, desc, T_MAP_LIVE, kp, kd, K, obs.T_map_kf, params, global_mutual=False)
    assert len(il) > 190 and np.all(ik == il)



def _depth_noisy_observations(rng: np.random.Generator, n: int) -> list[KeyframeObservations]:
    """One keyframe; live and keyframe depths with the default depth noise model, live and
    keyframe pixels with 1 px noise (the model's `keypoint_sigma_px` on both sides); the
    observations carry the map's (noisy) keyframe depth."""
    p = RefineParams()
    T_map_kf = KF_POSES[1]
    uv = rng.uniform([20, 20], [620, 460], size=(n, 2))
    z = rng.uniform(1.0, 3.5, size=n)
    pts = np.column_stack([(uv[:, 0] - 320) / 500 * z, (uv[:, 1] - 240) / 500 * z, z])
    T_kl = np.linalg.inv(T_map_kf) @ T_MAP_LIVE
    q = pts @ T_kl[:3, :3].T + T_kl[:3, 3]
    px = q[:, :2] / q[:, 2:3] * 500 + [320, 240] + rng.normal(0, 1.0, size=(n, 2))
    z_live = z + rng.normal(0, 1, n) * (p.depth_sigma_a * z**2 + p.depth_sigma_b)
    uv_live = uv + rng.normal(0, 1.0, size=(n, 2))
    live = np.column_stack([(uv_live[:, 0] - 320) / 500 * z_live, (uv_live[:, 1] - 240) / 500 * z_live, z_live])
    z_kf = q[:, 2] + rng.normal(0, 1, n) * (p.depth_sigma_a * q[:, 2] ** 2 + p.depth_sigma_b)
    return [KeyframeObservations(0, live, px, K, T_map_kf, z_kf)]


def test_map_depth_terms_are_whitened_by_both_depths_noise() -> None:
    """Monte Carlo with live depth, map depth and pixels noisy exactly as the model says: the
    3D terms' covariance holds ~95 % of the errors in its 95 % ellipsoid (systematic terms off)."""
    p = RefineParams(min_keyframes=1, sigma_sys_t_m=0.0, sigma_sys_r_deg=0.0, min_sigma_t_m=0.0,
                     min_sigma_r_deg=0.0, sigma_sys_t_per_rad=0.0, sigma_sys_r_per_rad=0.0,
                     sigma_sys_t_per_m=0.0, sigma_sys_r_deg_per_m=0.0)
    rng = np.random.default_rng(4)
    _assert_calibrated([_nees(refine_pose(T_MAP_LIVE, _depth_noisy_observations(rng, 60), p)) for _ in range(60)])


def test_map_depth_pulls_the_pose_where_the_map_has_it() -> None:
    """Exact data: the exact pose with the map's depth on half the points (NaN elsewhere:
    reprojections there). Then the map's depth 4 cm deeper everywhere: with `map_depth` the pose
    follows the points along the keyframe's optical axis; without, it ignores the depth."""
    exact = _observations(np.random.default_rng(5), 80, 0.0)
    T_kl = np.linalg.inv(exact[0].T_map_kf) @ T_MAP_LIVE
    z_kf = (exact[0].points_live @ T_kl[:3, :3].T + T_kl[:3, 3])[:, 2]
    half = z_kf.copy()
    half[::2] = np.nan
    T0 = T_MAP_LIVE @ make_T(so3_exp(np.radians([0.3, 0, 0])), np.array([0.01, 0, 0]))
    res = refine_pose(T0, [replace(exact[0], depth_kf=half), exact[1]], RefineParams())
    assert res.accepted, res.reason
    dt, dr = _err(res.T_map_camera)
    assert np.linalg.norm(dt) < 1e-4 and np.linalg.norm(dr) < 1e-5
    deeper = [replace(exact[0], depth_kf=z_kf + 0.04)]
    on = refine_pose(T_MAP_LIVE, deeper, RefineParams(min_keyframes=1, gate_px=40))
    off = refine_pose(T_MAP_LIVE, deeper, RefineParams(min_keyframes=1, map_depth=False))
    kf_axis = exact[0].T_map_kf[:3, 2]
    assert np.linalg.norm(off.T_map_camera[:3, 3] - T_MAP_LIVE[:3, 3]) < 1e-6
    assert (on.T_map_camera[:3, 3] - T_MAP_LIVE[:3, 3]) @ kf_axis > 0.02  # the live view moves with the points
