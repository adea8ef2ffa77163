"""Which keyframes a map update's changed-place candidates replace (`MapUpdate.finish`).

A candidate for a *changed place* (keyframes cover its place but no longer match it) is judged
on the session's other frames, never on itself: the *held-out* frames of a pose are the
update's well-matched observations within `place_radius_m` / `place_angle_deg` of it, the
`held_out_frames` nearest. A score is the median, over held-out frames, of the matches the
frame's pose explains with a keyframe (`MapUpdate._consistent`). Then:

* a candidate whose score on its own held-out frames is below `changed_max_consistent` (it
  does not localize the place's other frames either) or not `min_gain` above the best old
  keyframe's there is dropped: a keyframe is never replaced by, nor joined by, one that is not
  measurably better;
* an old keyframe at the candidate's place is *stale* when, on the held-out frames of its own
  pose, it scores below `changed_max_consistent`; the candidate replaces it (it is retired)
  only when the candidate scores at least `changed_max_consistent` and `min_gain` more on those
  same frames. Old keyframes that still match, or whose frames the candidate does not explain
  (they view other things), stay;
* a place never holds more than `max_per_place` keyframes that explain its frames: a candidate
  is dropped where old keyframes still scoring `changed_max_consistent` on its held-out frames
  and candidates already added there reach the cap (keyframes within the radius that do not
  explain those frames view other things and do not count);
* with fewer than `min_held_out` held-out frames nothing can be measured: the candidate
  replaces nothing and is added only where fewer than `max_per_place` keyframes lie within
  the place radius and angle at all.

Pure: poses, features and an injected scoring function in, decisions out.
"""

from __future__ import annotations

import enum
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from litevloc.base.params.map_maintenance import UpdateParams
from litevloc.pipelines.topomap.types import FeatureSet

F64 = NDArray[np.float64]
# (held-out frame index, keyframe features, T_map_keyframe 4x4, K 3x3) -> matches the frame's pose explains
ScoreFn = Callable[[int, FeatureSet, F64, F64], int]


class Outcome(enum.Enum):
    REPLACED = "replaced"  # added; stale keyframes at its place retired
    ADDED = "added"  # added beside old keyframes that still match (or none stale)
    NO_EVIDENCE = "no_evidence"  # too few held-out frames: added without replacing (below the cap)
    NOT_BETTER = "not_better"  # dropped: held-out frames match it no better than the old keyframes
    DENSE = "dense"  # dropped: its place already holds max_per_place keyframes


@dataclass(frozen=True)
class Decision:
    """What happened to one candidate: its place's old keyframes and the held-out scores."""

    candidate: int
    outcome: Outcome
    place: tuple[int, ...]  # old keyframe ids at the candidate's place
    held_out: int  # held-out frames scored
    new_score: float  # median explained matches of the held-out frames with the candidate
    old_scores: dict[int, float] = field(default_factory=dict)
    replaced: tuple[int, ...] = ()

    @property
    def kept(self) -> bool:
        return self.outcome in (Outcome.REPLACED, Outcome.ADDED, Outcome.NO_EVIDENCE)


def same_place(T_a: F64, T_b: F64, radius_m: float, cos_angle: float) -> bool:
    """Two camera poses (4x4, map frame) within `radius_m` and viewing within the angle."""
    return bool(np.linalg.norm(T_a[:3, 3] - T_b[:3, 3]) <= radius_m and float(T_a[:3, 2] @ T_b[:3, 2]) >= cos_angle)


@dataclass(frozen=True)
class Keyframes:
    """Old keyframes as the planner reads them: poses (N, 4, 4), intrinsics (N, 3, 3), features."""

    T_map_camera: F64
    K: F64
    features: Sequence[FeatureSet]


def plan_replacements(
    old: Keyframes, candidates: Sequence[tuple[int, F64, FeatureSet, F64]], probes: Sequence[tuple[int, F64]],
    score: ScoreFn, params: UpdateParams, retired: set[int], new_places: bool = False,
) -> list[Decision]:
    """Decisions for changed-place candidates `(frame index, T_map_camera, features, K)`, in order;
    `probes` are the held-out pool `(frame index, T_map_camera)`; `score(probe, ...)` counts a
    probe's explained matches with a keyframe. Old keyframes in `retired` (already retired by
    the visit rule) count for nothing; the caller retires `Decision.replaced` too.

    `new_places`: the candidates are of places no keyframe covers; each replaces the stale
    keyframes within `match_radius_m` (and the place angle) that it explains, and is always kept."""
    p, rp = params, params.replace
    cos = float(np.cos(np.radians(p.place_angle_deg)))
    gone = set(retired)
    added: list[F64] = []
    out: list[Decision] = []
    thr = p.changed_max_consistent
    for k, (index, T, feats, K) in enumerate(candidates):
        reach = p.match_radius_m if new_places else p.place_radius_m
        place = tuple(n for n in range(len(old.T_map_camera)) if n not in gone
                      and same_place(old.T_map_camera[n], T, reach, cos))
        def held_out(T_at: F64, index: int = index) -> list[tuple[int, F64]]:
            return sorted((q for q in probes if q[0] != index and same_place(q[1], T_at, p.place_radius_m, cos)),
                          key=lambda q: float(np.linalg.norm(q[1][:3, 3] - T_at[:3, 3])))[: rp.held_out_frames]

        def median(frames: list[tuple[int, F64]], f: FeatureSet, T_kf: F64, K_kf: F64) -> float:
            return float(np.median([score(q[0], f, T_kf, K_kf) for q in frames])) if frames else float("nan")

        held = held_out(T)
        added_here = sum(same_place(a, T, p.place_radius_m, cos) for a in added)
        density = len(place) + added_here
        if new_places:
            stale = tuple(n for n in place if _replaces(held_out(old.T_map_camera[n]), n, median, old, feats, T, K,
                                                        thr, rp.min_gain))
            d = Decision(k, Outcome.REPLACED if stale else Outcome.ADDED, place, len(held), median(held, feats, T, K),
                         replaced=stale)
        elif len(held) < rp.min_held_out:
            d = Decision(k, Outcome.NO_EVIDENCE if density < rp.max_per_place else Outcome.DENSE, place, len(held),
                         float("nan"))
        else:
            new = median(held, feats, T, K)
            olds = {n: median(held, old.features[n], old.T_map_camera[n], old.K[n]) for n in place}
            best_old = max(olds.values(), default=0.0)
            stale = tuple(n for n in place if _replaces(held_out(old.T_map_camera[n]), n, median, old, feats, T, K,
                                                        thr, rp.min_gain))
            if new < thr or new < best_old + rp.min_gain:
                outcome = Outcome.NOT_BETTER
            elif sum(olds[n] >= thr for n in place) + added_here >= rp.max_per_place:
                outcome = Outcome.DENSE
            else:
                outcome = Outcome.REPLACED if stale else Outcome.ADDED
            d = Decision(k, outcome, place, len(held), new, olds, stale if outcome is Outcome.REPLACED else ())
        if d.kept:
            added.append(T)
            gone.update(d.replaced)
        out.append(d)
    return out


def _replaces(frames: list[tuple[int, F64]], n: int, median: Callable[[list[tuple[int, F64]], FeatureSet, F64, F64],
                                                                     float],
              old: Keyframes, feats: FeatureSet, T: F64, K: F64, thr: int, min_gain: float) -> bool:
    """Whether the candidate (`feats`, `T`, `K`) replaces old keyframe `n`: on the held-out
    `frames` at n's own pose, n is stale (< `thr`) and the candidate reaches `thr` and `min_gain` more."""
    if not frames:
        return False
    was = median(frames, old.features[n], old.T_map_camera[n], old.K[n])
    now = median(frames, feats, T, K)
    return was < thr and now >= thr and now >= was + min_gain
