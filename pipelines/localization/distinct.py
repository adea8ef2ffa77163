"""Distinctiveness of a GL pose: does another place verify nearly as well?

Without a prior, a pose verified at one period of a repeating texture (a corridor, a row of
identical doors) is as convincing as the true one; the only evidence against it is that a
candidate at another pose verifies too. `strongest_rival` finds, among the verified candidates
of one GL query, the one with the most PnP inliers whose pose differs from the winner's by
more than a place's extent; `LocalizationParams.distinctiveness.ratio` decides whether the winner
stands out from it (the goal planner refuses a goal image that verifies at two places the same
way, `pipelines.navigation.planner`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from litevloc.base.geometry import relative_pose_error


@dataclass(frozen=True)
class VerifiedPose:
    """One GL candidate's PnP outcome: keyframe `node`, the pose it implies (4x4
    `T_map_camera`, metres) and its PnP inliers (whether or not it passed the gates)."""

    node: int
    T_map_camera: NDArray[np.float64]
    n_inliers: int


@dataclass(frozen=True)
class Rival:
    """The strongest candidate at another place: its keyframe, inliers, and how far its pose
    lies from the winner's (m, degrees)."""

    node: int
    n_inliers: int
    apart_m: float
    apart_deg: float


def same_place(T_a: NDArray[np.float64], T_b: NDArray[np.float64], apart_m: float, apart_deg: float) -> bool:
    """Whether two camera poses (4x4 T_map_camera) are one place for the test: within
    `apart_m` of each other and turned by at most `apart_deg`."""
    dt, dr = relative_pose_error(T_a, T_b)
    return bool(dt <= apart_m and dr <= apart_deg)


def strongest_rival(T_winner: NDArray[np.float64], verified: Sequence[VerifiedPose], apart_m: float,
                    apart_deg: float) -> Rival | None:
    """The verified candidate with the most inliers whose pose lies farther than `apart_m`
    from `T_winner` (4x4 T_map_camera) or turned more than `apart_deg` from it; None if every
    candidate agrees with the winner."""
    best: Rival | None = None
    for v in verified:
        elsewhere = not same_place(v.T_map_camera, T_winner, apart_m, apart_deg)
        if elsewhere and (best is None or v.n_inliers > best.n_inliers):
            dt, dr = relative_pose_error(v.T_map_camera, T_winner)
            best = Rival(v.node, v.n_inliers, float(dt), float(dr))
    return best


def ambiguity(winner_node: int, winner_inliers: int, rival: Rival | None, ratio: float) -> str:
    """The refusal reason when `rival` has more than 1/`ratio` of the winner's PnP inliers,
    else '' (also when there is no rival or `ratio` is 0: the test is off)."""
    if rival is None or ratio <= 0 or rival.n_inliers * ratio < winner_inliers:
        return ""
    return (f"ambiguous: node {winner_node} ({winner_inliers} inliers) and node {rival.node} "
            f"({rival.n_inliers}) verify poses {rival.apart_m:.2f} m / {rival.apart_deg:.0f} deg apart "
            f"(need x{ratio:g})")


def rivals_to_verify(later: Sequence[int], rerank_counts: Mapping[int, int], winner: int, ratio: float,
                     max_rivals: int) -> list[int]:
    """The `later` candidates (node ids, in GL order) worth verifying after `winner` for the
    test, at most `max_rivals`: those whose re-ranking count (`rerank_counts`, mutual nearest
    neighbours with the live frame; a node without one passes) is at least 1/`ratio` of the
    winner's."""
    need = rerank_counts.get(winner, 0) / ratio
    return [n for n in later if rerank_counts.get(n, need) >= need][:max_rivals]
