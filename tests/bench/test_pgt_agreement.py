"""bench/pgt_agreement.py: reading a COLMAP-convention pose file and aligning a second
reference (similarity + constant camera rotation) on one part of a trajectory."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from litevloc.base import geometry as g
from tests.bench import load_bench


def _poses(n: int, seed: int = 0) -> dict[int, np.ndarray]:
    rng = np.random.default_rng(seed)
    return {i: g.make_T(g.so3_exp(rng.normal(0, 0.6, 3)), rng.uniform(-2, 2, 3)) for i in range(n)}


def test_reads_world_to_camera_lines_of_one_sequence(tmp_path: Path) -> None:
    pa = load_bench("pgt_agreement")
    T = g.make_T(g.so3_exp(np.array([0.1, -0.2, 0.3])), np.array([0.5, -1.0, 2.0]))
    T_cw = np.linalg.inv(T)
    qx, qy, qz, qw = Rotation.from_matrix(T_cw[:3, :3]).as_quat()
    tx, ty, tz = T_cw[:3, 3]
    f = tmp_path / "pgt.txt"
    f.write_text(f"seq-01/frame-000007.color.png {qw} {qx} {qy} {qz} {tx} {ty} {tz} 525.5\n"
                 f"seq-02/frame-000007.color.png 1 0 0 0 0 0 0 525.5\n")
    got = pa.read_pgt(f, "seq-01")
    assert list(got) == [7]
    np.testing.assert_allclose(got[7], T, atol=1e-9)


def test_alignment_fitted_on_the_first_half_recovers_a_similarity_and_camera_rotation() -> None:
    pa = load_bench("pgt_agreement")
    ours = _poses(60)
    s, R = 1.05, g.so3_exp(np.array([0.2, -0.1, 0.4]))
    t, Rc = np.array([0.3, -0.7, 1.1]), g.so3_exp(np.array([0.0, 0.1, 0.03]))
    other = {}
    for i, T in ours.items():
        o = np.eye(4)
        o[:3, :3] = R @ T[:3, :3] @ Rc
        o[:3, 3] = s * R @ T[:3, 3] + t
        other[i] = o
    other[45][:3, 3] += [0.1, 0.0, 0.0]  # the second half is not used for the fit
    s_fit, R_fit, t_fit, Rc_fit = pa.fit_alignment(ours, other, list(range(30)))
    assert abs(s_fit - s) < 1e-9
    np.testing.assert_allclose(R_fit, R, atol=1e-9)
    np.testing.assert_allclose(t_fit, t, atol=1e-9)
    np.testing.assert_allclose(Rc_fit, Rc, atol=1e-9)
    # after the alignment our frames land on the other reference's, except the one moved by 10 cm
    dt, dr = g.relative_pose_error(pa.apply_alignment(s_fit, R_fit, t_fit, Rc_fit, ours[10]), other[10])
    assert dt < 1e-9 and dr < 1e-6
    dt, dr = g.relative_pose_error(pa.apply_alignment(s_fit, R_fit, t_fit, Rc_fit, ours[45]), other[45])
    assert abs(dt - 0.1) < 1e-9 and dr < 1e-6
