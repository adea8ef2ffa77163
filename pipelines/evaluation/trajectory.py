"""Trajectory evaluation: TUM files, timestamp association, SE(3) alignment, ATE and RPE.

* TUM format: one pose per line `t tx ty tz qx qy qz qw`, `t` in seconds, `#` comments;
  the pose is `T_world_body` (body position and orientation in the world).
* `umeyama_se3` aligns without scale (rotation + translation), as evo's
  `align(correct_scale=False)` and the LiteVLoc paper's ATE.
* ATE is on translation only (metres), after aligning the estimate onto the reference.
* RPE per metre: for every start pose, the first pose at least `delta_m` of reference
  path length later closes a segment; the error is the translation norm of
  `inv(inv(G_i) G_j) inv(E_i) E_j` divided by the reference segment length — a
  dimensionless drift rate (m of error per m travelled).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from litevloc.base.errors import LiteVLocError
from litevloc.base.geometry import (
    GeometryError,
    invert,
    make_T,
    matrix_to_quat_xyzw,
    quat_xyzw_to_matrix,
)

F64 = NDArray[np.float64]


class TrajectoryError(LiteVLocError, ValueError):
    """Unreadable trajectory file or unusable trajectory data (the message says which)."""


def read_tum(path: str | Path) -> tuple[F64, F64]:
    """Read a TUM trajectory -> ((N,) times in seconds float64, (N, 4, 4) poses float64)."""
    p = Path(path)
    if not p.is_file():
        raise TrajectoryError(f"trajectory file not found: {p}")
    times: list[float] = []
    poses: list[F64] = []
    for lineno, line in enumerate(p.read_text(encoding="utf-8").splitlines(), 1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        parts = s.replace(",", " ").split()
        if len(parts) != 8:
            raise TrajectoryError(
                f"{p}:{lineno}: expected 8 numbers 't tx ty tz qx qy qz qw', got {len(parts)}"
            )
        try:
            v = np.array([float(x) for x in parts])
        except ValueError as exc:
            raise TrajectoryError(f"{p}:{lineno}: not a number: {exc}") from exc
        if not np.all(np.isfinite(v)):
            raise TrajectoryError(f"{p}:{lineno}: non-finite value")
        try:
            R = quat_xyzw_to_matrix(v[4:8])
        except GeometryError as exc:
            raise TrajectoryError(f"{p}:{lineno}: {exc}") from exc
        times.append(float(v[0]))
        poses.append(make_T(R, v[1:4]))
    if not times:
        raise TrajectoryError(f"{p}: no poses")
    t = np.array(times)
    if np.any(np.diff(t) < 0):
        raise TrajectoryError(f"{p}: timestamps are not sorted")
    return t, np.stack(poses)


def write_tum(path: str | Path, times_s: NDArray[np.floating], poses: NDArray[np.floating]) -> None:
    """Write (N,) times (seconds) and (N, 4, 4) poses as a TUM file (9 decimals in time)."""
    t = np.asarray(times_s, dtype=np.float64)
    P = np.asarray(poses, dtype=np.float64)
    if t.ndim != 1 or P.shape != (len(t), 4, 4):
        raise TrajectoryError(f"need (N,) times and (N,4,4) poses, got {t.shape} and {P.shape}")
    lines = ["# t tx ty tz qx qy qz qw"]
    for ti, T in zip(t, P, strict=True):
        q = matrix_to_quat_xyzw(T[:3, :3])
        x, y, z = T[:3, 3]
        lines.append(
            f"{ti:.9f} {x:.9f} {y:.9f} {z:.9f} {q[0]:.9f} {q[1]:.9f} {q[2]:.9f} {q[3]:.9f}"
        )
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text("\n".join(lines) + "\n", encoding="utf-8")


def associate(
    t_a: NDArray[np.floating], t_b: NDArray[np.floating], max_dt: float
) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Match timestamps of two sorted series: for each a, the nearest b within max_dt.

    Returns index arrays (ia, ib) of equal length, each b used at most once (the closer
    a wins), sorted by ia. Same rule as evo's `associate_trajectories` for unique nearest
    matches. Times in any unit as long as both and max_dt share it.
    """
    a = np.asarray(t_a, dtype=np.float64)
    b = np.asarray(t_b, dtype=np.float64)
    if len(a) == 0 or len(b) == 0:
        return np.zeros(0, dtype=np.intp), np.zeros(0, dtype=np.intp)
    j = np.searchsorted(b, a)
    j0 = np.clip(j - 1, 0, len(b) - 1)
    j1 = np.clip(j, 0, len(b) - 1)
    pick = np.where(np.abs(b[j0] - a) <= np.abs(b[j1] - a), j0, j1)
    dt = np.abs(b[pick] - a)
    ok = dt <= max_dt
    ia = np.nonzero(ok)[0]
    ib = pick[ok]
    # Unique b: keep the closest a for each b.
    best: dict[int, int] = {}
    for i, jj in zip(ia, ib, strict=True):
        k = int(jj)
        if k not in best or dt[i] < dt[best[k]]:
            best[k] = int(i)
    keep = np.array(sorted(best.values()), dtype=np.intp)
    return keep, pick[keep].astype(np.intp)


def umeyama_se3(src: NDArray[np.floating], dst: NDArray[np.floating]) -> F64:
    """Rigid transform (no scale) minimising sum |dst_i - (R src_i + t)|^2 (Umeyama 1991).

    src, dst: (N, 3) points, N >= 3 not collinear for a unique rotation. Returns 4x4 T
    with dst ~ T * src.
    """
    X = np.asarray(src, dtype=np.float64)
    Y = np.asarray(dst, dtype=np.float64)
    if X.shape != Y.shape or X.ndim != 2 or X.shape[1] != 3 or len(X) < 3:
        raise TrajectoryError(
            f"umeyama needs two (N>=3, 3) arrays of equal shape, got {X.shape} and {Y.shape}"
        )
    mx, my = X.mean(0), Y.mean(0)
    C = (Y - my).T @ (X - mx) / len(X)
    U, _, Vt = np.linalg.svd(C)
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        S[2, 2] = -1.0
    R = U @ S @ Vt
    return make_T(R, my - R @ mx)


@dataclass(frozen=True)
class ErrorStats:
    """Statistics of per-pose errors (metres for ATE, m/m for RPE per metre)."""

    rmse: float
    mean: float
    median: float
    max: float
    n: int

    @classmethod
    def of(cls, e: NDArray[np.floating]) -> ErrorStats:
        e = np.asarray(e, dtype=np.float64)
        if len(e) == 0:
            raise TrajectoryError("no errors to summarise (empty association)")
        return cls(
            float(np.sqrt(np.mean(e**2))),
            float(np.mean(e)),
            float(np.median(e)),
            float(np.max(e)),
            len(e),
        )


@dataclass(frozen=True)
class AteResult(ErrorStats):
    """ATE (translation, metres) and the alignment used (`T_ref_est`, 4x4)."""

    T_ref_est: F64 = field(default_factory=lambda: np.eye(4))


def _check_pair(est: NDArray[np.floating], ref: NDArray[np.floating]) -> tuple[F64, F64]:
    E = np.asarray(est, dtype=np.float64)
    G = np.asarray(ref, dtype=np.float64)
    if E.ndim != 3 or E.shape[1:] != (4, 4) or E.shape != G.shape:
        raise TrajectoryError(
            f"need two (N,4,4) pose arrays of equal length, got {E.shape} and {G.shape}"
        )
    return E, G


def ate(est: NDArray[np.floating], ref: NDArray[np.floating], align: bool = True) -> AteResult:
    """Absolute trajectory error of associated poses (N, 4, 4) est vs ref, translation only.

    With `align`, the estimate is first mapped onto the reference by `umeyama_se3` on the
    positions (no scale).
    """
    E, G = _check_pair(est, ref)
    T = umeyama_se3(E[:, :3, 3], G[:, :3, 3]) if align else np.eye(4)
    p = E[:, :3, 3] @ T[:3, :3].T + T[:3, 3]
    err = np.linalg.norm(p - G[:, :3, 3], axis=1)
    s = ErrorStats.of(err)
    return AteResult(s.rmse, s.mean, s.median, s.max, s.n, T)


def rpe_per_metre(
    est: NDArray[np.floating], ref: NDArray[np.floating], delta_m: float = 1.0
) -> ErrorStats:
    """Relative translation error per metre travelled over segments of >= delta_m path.

    est, ref: associated (N, 4, 4) poses. Raises TrajectoryError when the reference path
    is shorter than delta_m.
    """
    E, G = _check_pair(est, ref)
    if not delta_m > 0:
        raise TrajectoryError(f"delta_m must be > 0, got {delta_m}")
    steps = np.linalg.norm(np.diff(G[:, :3, 3], axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(steps)])
    j = np.searchsorted(s, s + delta_m, side="left")
    i = np.nonzero(j < len(s))[0]
    if len(i) == 0:
        raise TrajectoryError(
            f"reference path ({s[-1]:.3f} m) is shorter than delta_m = {delta_m} m"
        )
    j = j[i]
    dG = invert(G[i]) @ G[j]
    dE = invert(E[i]) @ E[j]
    err = np.linalg.norm((invert(dG) @ dE)[:, :3, 3], axis=1) / (s[j] - s[i])
    return ErrorStats.of(err)
