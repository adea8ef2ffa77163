"""Why a localization query was not localized, by kind; the published reason text is made from it.

Decisions branch on the kind (`QueryRefusal`); the words, with their numbers, are for people
(logs, diagnostics, benchmarks print them) and come from `refusal_text`.
"""

from __future__ import annotations

from enum import Enum


class QueryRefusal(Enum):
    """A query's outcome by kind (`NONE`: accepted)."""

    NONE = "none"
    NO_NODE_NEAR_PRIOR = "no node near the prior"  # LL: the prior is far from every map node (GL next)
    NO_CANDIDATE = "no candidate"  # LL: no candidate passed every check
    NO_VPR_CANDIDATE = "no VPR candidate"  # GL: no candidate passed every check
    UNCONFIRMED = "unconfirmed"  # GL: PnP verified a pose that no second keyframe confirmed
    AMBIGUOUS = "ambiguous"  # GL: another place verifies nearly as well (distinctiveness)
    SEES_THROUGH = "sees through"  # second look: the pose puts map points in front of the live depth
    HELD = "held"  # a pose its prior cannot confirm, held until a later frame repeats it
    HELD_ELSEWHERE = "held elsewhere"  # outside the prior's gate while a pose inside it awaits its repeat


_TEXT = {
    QueryRefusal.NONE: "ok",
    QueryRefusal.NO_NODE_NEAR_PRIOR: "no map node near the prior",
    QueryRefusal.NO_CANDIDATE: "not localized: no candidate verified",
    QueryRefusal.NO_VPR_CANDIDATE: "not localized: no VPR candidate verified",
    QueryRefusal.UNCONFIRMED: "not localized: no verified pose was confirmed by a second keyframe (last: node {node})",
    QueryRefusal.AMBIGUOUS: "not localized: {detail}",
    QueryRefusal.SEES_THROUGH: "not localized: {detail}",
    QueryRefusal.HELD: "not localized: {mode} pose held until a later frame repeats it ({detail})",
    QueryRefusal.HELD_ELSEWHERE: (
        "not localized: {dt_m:.2f} m / {dr_deg:.0f} deg from the prior, outside its gate ({gate_m:.2f} m), "
        "while a pose inside it held {dt_s:.2f} s before awaits its repeat"),
}


def refusal_text(kind: QueryRefusal, **numbers: object) -> str:
    """The reason text of `kind` with its numbers (`node`, `dt_m`, ...; `detail`: a check's own words)."""
    return _TEXT[kind].format(**numbers)
