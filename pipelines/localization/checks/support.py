"""The support check (GL): a pose resting on horizontal planes only is refused.

Floor and ceiling tiles repeat in every room and under 90-degree turns: a GL pose whose
supporting points all lie on one horizontal plane is no evidence of the place
(`support.min_height_m`), nor is one whose points lie on the floor and the ceiling alone: a
corridor seen from either end, or a tile period farther along, shows the same tiles above and
below (`support.min_off_layer_inliers`). Opt-in, any plane (`support.min_off_plane_inliers`): a
wall of repeating bricks seen alone verifies at every other copy of its texture. A weak candidate
accepted on the joint refinement's pooled inliers counts only the keyframes that pass the rule on
their own (`PooledSupportCheck`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from litevloc.base.params.localization import SupportParams
from litevloc.pipelines.localization.query import Query
from litevloc.pipelines.localization.results import CandidateAttempt
from litevloc.pipelines.localization.verifier import Candidate, CandidateVerifier
from litevloc.pipelines.pnp import PnpResult, Refusal


@dataclass(frozen=True, eq=False)
class SupportCheck:
    """GL's check of a PnP-verified candidate: refused when its pose rests on one horizontal plane."""

    verifier: CandidateVerifier

    def __call__(self, c: Candidate, q: Query) -> CandidateAttempt | None:
        assert c.res is not None and c.attempt is not None
        flat = flat_support(self.verifier, c.node, c.res, q)
        return replace(c.attempt, reason=flat, refusal=Refusal.LATER) if flat else None


@dataclass(frozen=True, eq=False)
class PooledSupportCheck:
    """GL's check of a weak candidate (fewer PnP inliers than `floor`) that passed pooled: only
    keyframes whose inliers under the joint pose do not rest on horizontal planes alone count in
    the pool (a keyframe refused for that as a candidate is no evidence pooled either), and those
    must still be `min_keyframes` explaining `floor` inliers together."""

    verifier: CandidateVerifier
    floor: int
    min_keyframes: int

    def __call__(self, c: Candidate, q: Query) -> CandidateAttempt | None:
        assert c.res is not None and c.attempt is not None
        if c.res.n_inliers >= self.floor or c.joint is None:
            return None
        up = np.asarray(self.verifier.map.grid.up, dtype=np.float64)
        flat = {k: flat_points_reason(np.asarray(pts, np.float64), up, q.params.support)
                for k, pts in c.joint.inlier_points_map().items()}
        kept = [k for k, why in flat.items() if not why]
        n = sum(c.joint.inliers_per_keyframe[k] for k in kept)
        if len(kept) >= self.min_keyframes and n >= self.floor:
            return None
        why = next((f"keyframe {k}: {w}" for k, w in flat.items() if w), "")
        return replace(c.attempt, refusal=Refusal.LATER, reason=(
            f"pooled support too weak ({n} inliers over {len(kept)} keyframe(s) not resting on floor and "
            f"ceiling alone; {why})"))


# Half the thickness of a horizontal layer: a floor's points under room-range depth noise and a
# right pose's tilt (fixed, not tuned).
LAYER_HALF_M = 0.05


def layer_share(heights: NDArray[np.float64], layers: int = 2, half_m: float = LAYER_HALF_M) -> float:
    """Share of the finite `heights` (N,) (metres along up) within `half_m` of the `layers`
    densest heights, each found among the points the denser ones left; 0 for no points."""
    h = np.asarray(heights, np.float64)
    h = h[np.isfinite(h)]
    return 1.0 - off_layers(h, layers, half_m) / len(h) if len(h) else 0.0


def off_layers(heights: NDArray[np.float64], layers: int = 2, half_m: float = LAYER_HALF_M) -> int:
    """How many of the finite `heights` (N,) (metres along up) lie farther than `half_m` from
    each of the `layers` densest heights (each found among the points the denser ones left)."""
    h = np.sort(np.asarray(heights, np.float64)[np.isfinite(heights)])
    left = np.ones(len(h), dtype=bool)
    for _ in range(layers):
        rest = h[left]
        if len(rest) == 0:
            break
        near = np.searchsorted(rest, rest + half_m, "right") - np.searchsorted(rest, rest - half_m, "left")
        left &= np.abs(h - rest[int(np.argmax(near))]) > half_m
    return int(left.sum())


def support_points(verifier: CandidateVerifier, node: int, T_map_camera: NDArray[np.float64],
                   q: Query) -> NDArray[np.float64]:
    """(N, 3) map-frame points (m) of the matches with keyframe `node` that the camera pose
    `T_map_camera` (4x4, map frame) explains."""
    explained, pts = verifier.explained_matches(node, T_map_camera, q)
    return np.asarray(pts[explained], np.float64)


def off_plane(points: NDArray[np.float64], half_m: float = LAYER_HALF_M, tries: int = 200) -> int:
    """How many of the finite `points` (N, 3, metres) lie farther than `half_m` from the plane that
    holds most of them (RANSAC over `tries` point triples, seeded: the same points give the same
    count); all of them for fewer than three points."""
    P = np.asarray(points, np.float64)
    P = P[np.isfinite(P).all(axis=1)]
    if len(P) < 3:
        return len(P)
    rng = np.random.default_rng(0)
    best = 0
    for _ in range(tries):
        a, b, c = P[rng.choice(len(P), 3, replace=False)]
        n = np.cross(b - a, c - a)
        norm = float(np.linalg.norm(n))
        if norm < 1e-9:
            continue
        best = max(best, int((np.abs((P - a) @ (n / norm)) <= half_m).sum()))
        if best == len(P):
            break
    return len(P) - best


def flat_reason(verifier: CandidateVerifier, node: int, T_map_camera: NDArray[np.float64], q: Query) -> str:
    """Why the pose `T_map_camera` (4x4) through keyframe `node` rests on horizontal planes only
    under the query's `support` parameters ('' where it does not, or the checks are off)."""
    sp = q.params.support
    if sp.min_height_m <= 0 and sp.min_off_layer_inliers <= 0 and sp.min_off_plane_inliers <= 0:
        return ""
    up = np.asarray(verifier.map.grid.up, dtype=np.float64)
    return flat_points_reason(support_points(verifier, node, T_map_camera, q), up, sp)


def flat_points_reason(pts: NDArray[np.float64], up: NDArray[np.float64], sp: SupportParams) -> str:
    """Why a pose whose support lies at `pts` (N, 3, map frame, m; `up` the map's (3,) up) rests on
    planes only under `sp`: the horizontal rules on the heights (`flat_heights_reason`), then the
    one-plane rule ('' where neither refuses, or `pts` is empty)."""
    why = flat_heights_reason(np.asarray(pts @ up, np.float64), sp)
    if why or sp.min_off_plane_inliers <= 0 or len(pts) == 0:
        return why
    off = off_plane(pts)
    if off < sp.min_off_plane_inliers:
        return (f"support on one plane only ({off} of {len(pts)} inliers off it < {sp.min_off_plane_inliers}: "
                "a wall of repeating bricks or tiles verifies its other copies)")
    return ""


def flat_heights_reason(h: NDArray[np.float64], sp: SupportParams) -> str:
    """Why a pose whose support lies at heights `h` (N,) (metres along the map's up) rests on
    horizontal planes only under `sp` ('' where it does not, or `h` is empty)."""
    if len(h) == 0:
        return ""
    lo, hi = np.percentile(h, [10.0, 90.0])  # the support's height span; near 0: one horizontal plane
    if sp.min_height_m > 0 and hi - lo < sp.min_height_m:
        return (f"support on one horizontal plane only (inliers span {hi - lo:.2f} m < {sp.min_height_m:g} "
                "along up: floor or ceiling tiles repeat)")
    off = off_layers(h) if sp.min_off_layer_inliers > 0 else 0
    if off < sp.min_off_layer_inliers:
        return (f"support on floor and ceiling only ({off} of {len(h)} inliers off the two densest horizontal "
                f"layers < {sp.min_off_layer_inliers}: floor and ceiling tiles repeat)")
    return ""


def flat_at(verifier: CandidateVerifier, node: int, T_map_camera: NDArray[np.float64], q: Query) -> bool:
    """Whether the pose `T_map_camera` (4x4) through keyframe `node` rests on horizontal planes only
    (`flat_reason`): such a pose is no evidence of a place, for GL's winner or for a rival of it."""
    return bool(flat_reason(verifier, node, T_map_camera, q))


def flat_support(verifier: CandidateVerifier, node: int, res: PnpResult, q: Query) -> str:
    """The refusal reason when a GL pose rests on horizontal planes only (`flat_reason`), else ''."""
    if res.T_target_source is None or res.n_inliers == 0:
        return ""
    return flat_reason(verifier, node, verifier.map.T_map_camera[node] @ res.T_target_source, q)
