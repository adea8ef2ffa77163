from __future__ import annotations

import numpy as np
import pytest

from litevloc.base import geometry as g
from litevloc.base.params.drift import DriftParams
from litevloc.pipelines.odometry_drift import simulate_odometry


def circle(n: int = 50) -> tuple[np.ndarray, np.ndarray]:
    times = np.arange(n, dtype=np.int64) * 100_000_000  # 10 Hz
    poses = np.stack([g.make_T(g.so3_exp(np.array([0, 0, a])), [np.cos(a), np.sin(a), 0.0])
                      for a in np.linspace(0, np.pi, n)])
    return times, poses


def test_noise_free_model_reproduces_relative_motion() -> None:
    times, poses = circle()
    zero = DriftParams(0, 0, 0, 0, 0)
    t, odom = simulate_odometry(times, poses, 50.0, zero, seed=1)
    assert t[0] == times[0] and np.allclose(odom[0], np.eye(4))
    assert len(t) == 5 * (len(times) - 1) + 1
    gt = np.stack([g.interpolate_pose_at(int(x), times, poses) for x in t])
    aligned = g.invert(poses[0]) @ gt
    assert np.allclose(odom, aligned, atol=1e-9)


def test_seeded_and_drifting() -> None:
    times, poses = circle()
    p = DriftParams()
    _, a = simulate_odometry(times, poses, 100.0, p, seed=7)
    _, b = simulate_odometry(times, poses, 100.0, p, seed=7)
    _, c = simulate_odometry(times, poses, 100.0, p, seed=8)
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    gt_end = g.invert(poses[0]) @ poses[-1]
    err = np.linalg.norm(a[-1][:3, 3] - gt_end[:3, 3])
    assert 1e-4 < err < 0.5  # drifts, but plausibly for ~3 m of path


def test_bad_params_and_inputs() -> None:
    with pytest.raises(ValueError, match="sigma_trans_per_m"):
        DriftParams(sigma_trans_per_m=-1)
    times, poses = circle()
    with pytest.raises(g.GeometryError):
        simulate_odometry(times[:1], poses[:1], 100.0, DriftParams(), 0)
    with pytest.raises(ValueError):
        simulate_odometry(times, poses, 0.0, DriftParams(), 0)
