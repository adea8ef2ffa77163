"""Trajectory evaluation: Umeyama, TUM I/O, association, ATE (cross-checked with evo), RPE."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from litevloc.base.geometry import make_T, so3_exp
from litevloc.experiments.fusion_sim import synthetic_trajectory
from litevloc.pipelines.evaluation.trajectory import (
    TrajectoryError,
    associate,
    ate,
    read_tum,
    rpe_per_metre,
    umeyama_se3,
    write_tum,
)


def _random_T(rng: np.random.Generator, t_scale: float = 2.0) -> np.ndarray:
    return make_T(so3_exp(rng.normal(size=3)), rng.normal(size=3) * t_scale)


def test_umeyama_recovers_a_known_transform() -> None:
    rng = np.random.default_rng(0)
    X = rng.normal(size=(50, 3)) * 3
    T = _random_T(rng)
    Y = X @ T[:3, :3].T + T[:3, 3]
    np.testing.assert_allclose(umeyama_se3(X, Y), T, atol=1e-10)
    # With noise it is still close, and a reflection is never returned.
    Yn = Y + rng.normal(size=Y.shape) * 0.01
    Te = umeyama_se3(X, Yn)
    assert np.linalg.det(Te[:3, :3]) > 0
    np.testing.assert_allclose(Te, T, atol=0.02)
    with pytest.raises(TrajectoryError):
        umeyama_se3(X[:2], Y[:2])


def test_tum_roundtrip_and_errors(tmp_path: Path) -> None:
    _, P = synthetic_trajectory(5.0, 10.0, seed=1)
    t = np.arange(len(P)) * 0.1 + 1234.5
    write_tum(tmp_path / "a.txt", t, P)
    t2, P2 = read_tum(tmp_path / "a.txt")
    np.testing.assert_allclose(t2, t, atol=1e-9)
    np.testing.assert_allclose(P2, P, atol=1e-8)
    bad = tmp_path / "bad.txt"
    bad.write_text("0 1 2 3 0 0 0\n")
    with pytest.raises(TrajectoryError, match=r"bad.txt:1: expected 8"):
        read_tum(bad)
    with pytest.raises(TrajectoryError, match="not found"):
        read_tum(tmp_path / "missing.txt")


def test_associate_nearest_unique_within_max_dt() -> None:
    a = np.array([0.0, 1.0, 2.0, 3.0, 4.0])
    b = np.array([0.004, 1.02, 1.995, 2.003, 9.0])
    ia, ib = associate(a, b, 0.01)
    assert ia.tolist() == [0, 2] and ib.tolist() == [
        0,
        3,
    ]  # 1.02 is too far; 2.003 is nearer than 1.995
    ia, ib = associate(a, b, 0.05)
    assert ia.tolist() == [0, 1, 2] and ib.tolist() == [0, 1, 3]
    ia, ib = associate(
        np.array([1.0, 1.004]), np.array([1.003]), 0.01
    )  # one b, two a: the closer a wins
    assert ia.tolist() == [1] and ib.tolist() == [0]


def test_ate_and_rpe_basic() -> None:
    _, G = synthetic_trajectory(60.0, 10.0, seed=3)
    rng = np.random.default_rng(1)
    T = _random_T(rng)
    E = np.linalg.inv(T) @ G  # same trajectory in another frame
    r = ate(E, G)
    assert r.rmse < 1e-9 and r.n == len(G)
    np.testing.assert_allclose(r.T_ref_est, T, atol=1e-9)
    assert ate(E, G, align=False).rmse > 0.1
    assert rpe_per_metre(E, G, 1.0).max < 1e-9
    L = np.stack([make_T(np.eye(3), [0.05 * i, 0.0, 0.0]) for i in range(200)])  # straight 10 m
    S = L.copy()
    S[:, :3, 3] *= 1.1  # 10 % scale error -> 0.1 m error per metre travelled
    rp = rpe_per_metre(S, L, 1.0)
    assert rp.median == pytest.approx(0.1, rel=1e-6) and rp.max == pytest.approx(0.1, rel=1e-6)
    with pytest.raises(TrajectoryError, match="shorter"):
        rpe_per_metre(S, L, 1e6)


def test_ate_agrees_with_evo(tmp_path: Path) -> None:
    evo_sync = pytest.importorskip("evo.core.sync")
    from evo.core import metrics
    from evo.tools import file_interface

    gt_t, G = synthetic_trajectory(40.0, 30.0, seed=4)
    rng = np.random.default_rng(5)
    t_ref = gt_t * 1e-9 + 100.0
    # Estimate: other frame, noisy, at shifted times (2 ms) and with gaps.
    T = _random_T(rng)
    keep = np.sort(rng.choice(len(G), size=len(G) * 2 // 3, replace=False))
    E = np.stack(
        [
            np.linalg.inv(T)
            @ g
            @ make_T(so3_exp(rng.normal(size=3) * 0.01), rng.normal(size=3) * 0.03)
            for g in G[keep]
        ]
    )
    t_est = t_ref[keep] + 0.002
    write_tum(tmp_path / "ref.txt", t_ref, G)
    write_tum(tmp_path / "est.txt", t_est, E)

    tr, Pr = read_tum(tmp_path / "ref.txt")
    te, Pe = read_tum(tmp_path / "est.txt")
    ir, ie = associate(tr, te, 0.01)
    ours = ate(Pe[ie], Pr[ir])

    ref = file_interface.read_tum_trajectory_file(str(tmp_path / "ref.txt"))
    est = file_interface.read_tum_trajectory_file(str(tmp_path / "est.txt"))
    ref, est = evo_sync.associate_trajectories(ref, est, max_diff=0.01)
    est.align(ref, correct_scale=False)
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((ref, est))
    st = ape.get_all_statistics()
    assert ours.n == ref.num_poses
    assert abs(ours.rmse - st["rmse"]) < 1e-6
    assert abs(ours.median - st["median"]) < 1e-6
    assert abs(ours.max - st["max"]) < 1e-6
    assert abs(ours.mean - st["mean"]) < 1e-6
