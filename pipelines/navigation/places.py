"""Grouping the goal placement's candidates into places, and its ambiguity test (`unambiguous`):
a goal that verifies as well at another place is refused, unless the support off the floor and
ceiling tiles singles one place out."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from litevloc.base.params.navigation import GoalParams
from litevloc.pipelines.navigation.candidates import Candidate, GoalResult, distinctive_support, horizontal_share
from litevloc.pipelines.topomap.types import TopoMap


def group_places(cands: list[Candidate], agree_m: float, agree_deg: float,
            to_plane: Callable[[NDArray[np.float64]], NDArray[np.float64]],
            covisible: Callable[[int, int], bool] = lambda a, b: False) -> list[list[Candidate]]:
    """Candidates with a metric goal pose grouped into places: greedy, strongest PnP first; a
    candidate joins the first place whose seed pose lies within agree_m along the floor (the
    map grid's `to_plane`: a goal is a spot to drive to, and PnP's height is its least certain
    part) and agree_deg (angle between the optical axes) of its own, or whose
    seed's keyframe is covisible with its own (the map verified that the two keyframes see the
    same scene: in a long corridor the goal poses of neighbouring keyframes can differ by a
    metre, and that is one place)."""
    places: list[list[Candidate]] = []
    for c in sorted((c for c in cands if c.T_map_goal is not None), key=lambda c: -c.pose_inliers):
        assert c.T_map_goal is not None
        for place in places:
            seed = place[0].T_map_goal
            assert seed is not None
            if covisible(place[0].node, c.node) or _agree(seed, c.T_map_goal, agree_m, agree_deg, to_plane):
                place.append(c)
                break
        else:
            places.append([c])
    return places


def _agree(T_a: NDArray[np.float64], T_b: NDArray[np.float64], agree_m: float, agree_deg: float,
           to_plane: Callable[[NDArray[np.float64]], NDArray[np.float64]]) -> bool:
    """Whether two goal poses (4x4 T_map_goal) are one spot: within `agree_m` along the floor
    (`to_plane`) and `agree_deg` between their optical axes."""
    apart = float(np.linalg.norm(np.diff(to_plane(np.stack([T_a[:3, 3], T_b[:3, 3]])), axis=0)))
    return apart <= agree_m and float(T_a[:3, 2] @ T_b[:3, 2]) >= float(np.cos(np.radians(agree_deg)))


def _consensus(place: list[Candidate], agree_m: float, agree_deg: float,
               to_plane: Callable[[NDArray[np.float64]], NDArray[np.float64]]) -> Candidate:
    """The strongest place member (most PnP inliers) among those whose goal poses agree (`_agree`)
    with the pose the most PnP support agrees with: a member joined by covisibility can sit metres
    off, and so can the strongest one."""
    def agreeing(c: Candidate) -> list[Candidate]:
        assert c.T_map_goal is not None
        return [o for o in place
                if o.T_map_goal is not None and _agree(c.T_map_goal, o.T_map_goal, agree_m, agree_deg, to_plane)]

    centre = max(place, key=lambda c: (sum(o.pose_inliers for o in agreeing(c)), c.pose_inliers))
    return max(agreeing(centre), key=lambda c: c.pose_inliers)


def unambiguous(topomap: TopoMap, cands: list[Candidate], verified: list[Candidate], best: Candidate,
                 params: GoalParams, table: tuple[tuple[int, float, int], ...]) -> tuple[Candidate, GoalResult | None]:
    """The ambiguity test of `localize_goal`: candidates grouped into places; the goal is ambiguous
    when another place's PnP support exceeds 1/`ambiguity_ratio` of the chosen place's, unless
    (`ambiguity_band_m` > 0) one place with a verified candidate holds at least `pose_min_inliers`
    distinctive support points (not on floor or ceiling tiles) and `ambiguity_ratio` times any
    other place's: then that place is chosen. (the chosen candidate, None) or (-, the refusal); where
    the PnP supports single out the place, the candidate is the strongest pose of the group most of
    the place's support agrees with (`_consensus`; inliers and support its own) with `node` set to
    the place's keyframe nearest that pose."""
    covis = topomap.covisibility_lists
    places = group_places(cands, params.agree_m, params.agree_deg, topomap.grid.to_plane, lambda a, b: b in covis[a])
    support = [sum(c.pose_inliers for c in p) for p in places]
    mine = next(i for i, p in enumerate(places) if best in p)
    rivals = [(s, p[0]) for i, (s, p) in enumerate(zip(support, places, strict=True)) if i != mine]
    if not rivals or max(r[0] for r in rivals) * params.ambiguity_ratio <= support[mine]:
        # the place's pose comes from the poses most of its support agrees with; the robot drives
        # to the place's keyframe nearest that pose
        seed = _consensus(places[mine], params.agree_m, params.agree_deg, topomap.grid.to_plane)
        assert seed.T_map_goal is not None
        at = seed.T_map_goal[:3, 3]
        pos = np.asarray(topomap.positions, np.float64)
        near = min(places[mine], key=lambda c: float(np.linalg.norm(pos[c.node] - at)))
        return replace(seed, node=near.node), None
    if params.ambiguity_band_m > 0:  # tiles say nothing about the place: does the rest single one out?
        up = topomap.grid.up
        distinct = [distinctive_support(_support_map(topomap, p), up, params.ambiguity_band_m) for p in places]
        ok = [i for i, p in enumerate(places) if any(c in verified for c in p)]  # best's place is one
        w = max(ok, key=lambda i: (distinct[i], best in places[i]))
        other = max((d for i, d in enumerate(distinct) if i != w), default=0)
        if distinct[w] >= params.pose_min_inliers and other * params.ambiguity_ratio <= distinct[w]:
            return max((c for c in places[w] if c in verified), key=lambda c: (c.inliers, c.similarity)), None
    s_rival, rival = max(rivals, key=lambda r: r[0])
    assert rival.T_map_goal is not None and best.T_map_goal is not None
    apart = float(np.linalg.norm(rival.T_map_goal[:3, 3] - best.T_map_goal[:3, 3]))
    why = ""
    flat = horizontal_share(_support_map(topomap, [best]), topomap.grid.up)
    if flat >= 0.5:  # say what the image lacks, so the user can retake it
        why = (f"; {100 * flat:.0f} % of node {best.node}'s support lies on one "
               "horizontal surface (floor or ceiling tiles repeat): an image with more of the "
               "place in view would tell them apart")
    return best, GoalResult(None, best.inliers,
                            f"goal image is ambiguous: it verifies at nodes {best.node} and {rival.node}, "
                            f"{apart:.1f} m apart (PnP support {support[mine]} vs {s_rival}, need "
                            f"x{params.ambiguity_ratio:g}){why}", table, None, best.pose_inliers)


def _support_map(topomap: TopoMap, place: list[Candidate]) -> NDArray[np.float64]:
    """(N, 3) the PnP support points of a place's candidates in the map frame (metres)."""
    return np.concatenate([c.support_points @ topomap.T_map_camera[c.node][:3, :3].T
                           + topomap.T_map_camera[c.node][:3, 3] for c in place] + [np.zeros((0, 3))])
