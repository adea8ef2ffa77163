"""Ties between the odometry and the visual edges into one keyframe, broken by a skip edge.

The front end counts the visual edges into a new keyframe k as one vote (they all use k's
image) against the odometry's one, and a tie keeps the odometry (`frontend`). Two causes
look alike at k: an image aliased by a repeating texture (the odometry is right) and a
slipping wheel (vision is right). The next keyframe k+1 tells them apart with the skip edge
k-1 -> k+1, a visual edge that does not use the disputed image k:

* it agrees with the odometry's k-1 -> k -> k+1: the odometry stands (one odd image);
* it contradicts it, and agrees with vision's k-1 -> k followed by k -> k+1 (odometry or
  the visual edge k -> k+1: a slip may last): a second image sides with vision, two votes
  against one, and the odometry edge k-1 -> k is dropped for k's visual edges.

So a slow wheel slip is corrected, and one aliased image still cannot move the chain. A
texture that repeats along the path with a period of about the keyframe spacing can: then
the skip edge, too, matches the wrong repetition (the simulator's ring corridor: the skip
edge sided with visual edges 0.6 m off at every tie of a lap), so it is off unless
`slam.visual.skip_edge_ties` is set. Agreement is the front end's test
(`visual.max_disagreement_sigma` of the summed variances).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from litevloc.base.geometry import invert, rotation_angle
from litevloc.pipelines.slam.types import F64, Edge, Fault

ODOMETRY_KEPT = "odometry kept"
ODOMETRY_DROPPED = "odometry dropped"


@dataclass(eq=False)
class Dispute:
    """A keyframe whose visual edges (two or more) all contradict its odometry edge: the
    odometry edge `odometry` (k-1 -> k, kept unless the skip edge overturns it), the visual
    edges into k that agree among themselves, nearest keyframe first (`visual`), how many
    visual edges there were, and the outcome (`ODOMETRY_KEPT` / `ODOMETRY_DROPPED`)."""

    keyframe: int
    t_s: float
    odometry: Edge
    visual: list[Edge]
    n_visual: int
    outcome: str = ODOMETRY_KEPT


def agree(T_a: F64, T_b: F64, covariances: Sequence[F64], k_sigma: float) -> bool:
    """Do two estimates of one pose (4x4) agree within `k_sigma` of the summed variances of
    the edges behind them (6x6, GTSAM order: rotation first), largest axis?"""
    var = np.sum([np.diag(c) for c in covariances], axis=0)
    E = invert(T_a) @ T_b
    return bool(np.linalg.norm(E[:3, 3]) <= k_sigma * np.sqrt(var[3:].max())
                and rotation_angle(E[:3, :3]) <= k_sigma * np.sqrt(var[:3].max()))


def vision_wins(d: Dispute, T_before: F64, T_odometry: F64, T_vision: F64, skip: Edge, odometry_next: Edge,
                visual_next: Edge | None, k_sigma: float) -> bool:
    """The skip edge's verdict on dispute `d` (see the module docstring): `T_before` the pose of
    keyframe k-1, `T_odometry` / `T_vision` keyframe k's pose by the odometry / by its visual
    edges, `skip` the edge k-1 -> k+1, `odometry_next` and `visual_next` (None where it failed)
    the edges k -> k+1. True when vision wins."""
    via_skip = T_before @ skip.T_a_b
    if agree(via_skip, T_odometry @ odometry_next.T_a_b, [skip.covariance, d.odometry.covariance,
                                                          odometry_next.covariance], k_sigma):
        return False
    v = d.visual[0].covariance
    stories = [(odometry_next.T_a_b, odometry_next.covariance)]
    if visual_next is not None:
        stories.append((visual_next.T_a_b, visual_next.covariance))
    return any(agree(via_skip, T_vision @ T, [skip.covariance, v, C], k_sigma) for T, C in stories)


def dispute_faults(disputes: Sequence[Dispute]) -> list[Fault]:
    """One fault per run of consecutive disputed keyframes with the same outcome."""
    runs: list[list[Dispute]] = []
    for d in disputes:
        if runs and runs[-1][-1].keyframe == d.keyframe - 1 and runs[-1][-1].outcome == d.outcome:
            runs[-1].append(d)
        else:
            runs.append([d])
    out = []
    for run in runs:
        a, b, n, last = run[0].keyframe, run[-1].keyframe, len(run), run[-1]
        where = f"keyframes {a}-{b}"
        if last.outcome == ODOMETRY_DROPPED:
            out.append(Fault("odometry disagrees with vision", run[0].t_s,
                             f"{where}: the visual edges and the skip edge over the next keyframe contradict the "
                             f"odometry at {n} keyframe(s) (last at {last.t_s:.1f} s)",
                             "odometry edges dropped, visual edges kept (two images against the odometry: a wheel "
                             "slip)"))
        else:
            out.append(Fault("vision disagrees with odometry", run[0].t_s,
                             f"{where}: all {last.n_visual} visual edges contradict the odometry at {n} keyframe(s) "
                             f"(last at {last.t_s:.1f} s)",
                             "visual edges dropped, odometry kept (the new keyframe's image is one vote against the "
                             "odometry's one; a tie keeps the odometry)"))
    return out
