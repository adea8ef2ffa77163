"""The support check (GL): a pose resting on one horizontal plane only is refused.

Floor and ceiling tiles repeat in every room and under 90-degree turns: a GL pose whose
supporting points all lie on one horizontal plane is no evidence of the place.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

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


def support_height_spread(verifier: CandidateVerifier, node: int, res: PnpResult, q: Query) -> float:
    """Extent (m) along the map's up vector of the points that support a verified pose (10th to
    90th percentile of the heights of the matches it explains, `CandidateVerifier.explained_matches`);
    inf when the pose or the support is missing. Near 0: every supporting point lies on one
    horizontal plane (the floor or the ceiling)."""
    if res.T_target_source is None or res.n_inliers == 0:
        return float("inf")
    return height_spread_at(verifier, node, verifier.map.T_map_camera[node] @ res.T_target_source, q)


def height_spread_at(verifier: CandidateVerifier, node: int, T_map_camera: NDArray[np.float64], q: Query) -> float:
    """`support_height_spread` of the matches with keyframe `node` that the camera pose
    `T_map_camera` (4x4, map frame) explains; inf without such matches."""
    m = verifier.map
    explained, pts = verifier.explained_matches(node, T_map_camera, q)
    pts = pts[explained]
    if len(pts) == 0:
        return float("inf")
    h = pts @ np.asarray(m.grid.up, dtype=np.float64)
    lo, hi = np.percentile(h, [10.0, 90.0])
    return float(hi - lo)


def flat_at(verifier: CandidateVerifier, node: int, T_map_camera: NDArray[np.float64], q: Query) -> bool:
    """Whether the pose `T_map_camera` (4x4) through keyframe `node` rests on one horizontal plane
    under the query's `support.min_height_m` (never when the check is off): such a pose is no
    evidence of a place, for GL's winner or for a rival of it."""
    need = q.params.support.min_height_m
    return need > 0 and height_spread_at(verifier, node, T_map_camera, q) < need


def flat_support(verifier: CandidateVerifier, node: int, res: PnpResult, q: Query) -> str:
    """The refusal reason when a GL pose rests on one horizontal plane only (see
    `LocalizationParams.support.min_height_m`, the query's), else ''."""
    need = q.params.support.min_height_m
    if need <= 0:
        return ""
    spread = support_height_spread(verifier, node, res, q)
    if spread >= need:
        return ""
    return (f"support on one horizontal plane only (inliers span {spread:.2f} m < {need:g} "
            "along up: floor or ceiling tiles repeat)")
