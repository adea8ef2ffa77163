"""Changed-place candidates replace stale keyframes (`pipelines.topomap.replace`), judged on
held-out frames: a synthetic building whose places change every cycle, with a scoring function
that says which keyframe matches which frame."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from litevloc.base.params.map_maintenance import ReplaceParams, UpdateParams
from litevloc.pipelines.topomap.replace import Keyframes, Outcome, plan_replacements

K = np.eye(3)
PARAMS = UpdateParams()


@dataclass(frozen=True)
class Look:
    """Stand-in features: what a keyframe shows (a place id, and the 'epoch' of its appearance)."""

    place: int
    epoch: int


def pose(x: float, yaw_deg: float = 0.0) -> NDArray[np.float64]:
    T = np.eye(4)
    a = np.radians(yaw_deg)
    T[:3, :3] = [[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]]
    T[0, 3] = x
    return T


class Building:
    """Places 2 m apart along x; a frame at place p in epoch e is matched `quality[(p, e)]` times by a
    keyframe showing place p with appearance e, and nothing else."""

    def __init__(self, places: int) -> None:
        self.places = places
        self.frames: dict[int, tuple[int, int]] = {}  # frame index -> (place, epoch)
        self.quality: dict[tuple[int, int], int] = {}

    def score(self, frame: int, feats: object, T: NDArray[np.float64], K_: NDArray[np.float64]) -> int:
        assert isinstance(feats, Look)
        place, epoch = self.frames[frame]
        return self.quality.get((place, epoch), 100) if (feats.place, feats.epoch) == (place, epoch) else 0

    def visit(self, epoch: int, start: int) -> tuple[list[tuple[int, NDArray[np.float64], Look, NDArray[np.float64]]],
                                                     list[tuple[int, NDArray[np.float64]]]]:
        """One session in `epoch`: per place a candidate and two other frames (the held-out pool)."""
        cands, probes = [], []
        for p in range(self.places):
            for k, dx in enumerate((0.0, 0.1, -0.1)):
                i = start + 3 * p + k
                self.frames[i] = (p, epoch)
                probes.append((i, pose(2.0 * p + dx)))
                if k == 0:
                    cands.append((i, pose(2.0 * p), Look(p, epoch), K))
        return cands, probes


def keyframes(nodes: list[tuple[NDArray[np.float64], Look]]) -> Keyframes:
    return Keyframes(np.stack([T for T, _ in nodes]), np.stack([K] * len(nodes)), [f for _, f in nodes])  # type: ignore


def test_size_stays_bounded_over_cycles_of_change() -> None:
    b = Building(6)
    nodes = [(pose(2.0 * p), Look(p, 0)) for p in range(b.places)]
    for cycle in range(1, 11):  # every place changes every cycle
        cands, probes = b.visit(cycle, 100 * cycle)
        decisions = plan_replacements(keyframes(nodes), cands, probes, b.score, PARAMS, set())
        assert [d.outcome for d in decisions] == [Outcome.REPLACED] * b.places
        gone = {n for d in decisions for n in d.replaced}
        nodes = [x for n, x in enumerate(nodes) if n not in gone] + [(c[1], c[2]) for c, d in
                                                                      zip(cands, decisions, strict=True) if d.kept]
        assert len(nodes) == b.places, cycle
        assert {f.epoch for _, f in nodes} == {cycle}


def test_a_worse_candidate_never_replaces_a_good_keyframe() -> None:
    b = Building(1)
    nodes = [(pose(0.0), Look(0, 0))]
    cands, probes = b.visit(0, 0)  # the same appearance as the keyframe ...
    b.quality[(0, 0)] = 80
    worse = [(cands[0][0], pose(0.05), Look(0, 0), K)]
    b.quality[(0, 0)] = 80
    d, = plan_replacements(keyframes(nodes), worse, probes, b.score, PARAMS, set())
    assert d.outcome is Outcome.NOT_BETTER and d.replaced == ()  # ... explains no more than it: dropped
    # a candidate that localizes nothing of its place is dropped even where the keyframe is stale
    cands, probes = b.visit(1, 10)
    b.quality[(0, 1)] = PARAMS.changed_max_consistent - 1
    d, = plan_replacements(keyframes(nodes), cands, probes, b.score, PARAMS, set())
    assert d.outcome is Outcome.NOT_BETTER and d.replaced == ()


def test_unchanged_places_and_keyframes_viewing_other_things_are_kept() -> None:
    b = Building(3)
    nodes = [(pose(2.0 * p), Look(p, 0)) for p in range(b.places)]
    # a keyframe 0.3 m from place 1 looking 20 deg away sees another thing (place 7, unchanged)
    nodes.append((pose(2.3, 20.0), Look(7, 0)))
    b.frames.update({900: (7, 0), 901: (7, 0)})
    cands, probes = b.visit(1, 0)
    probes += [(900, pose(2.3, 20.0)), (901, pose(2.35, 20.0))]
    cands = [cands[1]]  # only place 1 changed
    params = UpdateParams(replace=ReplaceParams(held_out_frames=2))  # each pose judged by its two nearest frames
    d, = plan_replacements(keyframes(nodes), cands, probes, b.score, params, set())
    assert d.outcome is Outcome.REPLACED and d.replaced == (1,)
    assert 3 in d.place  # the other-things keyframe is at the place, and kept: its own frames still match it
    assert {0, 2}.isdisjoint(d.place)  # unchanged places are not even looked at


def test_density_cap_and_no_evidence() -> None:
    b = Building(1)
    nodes = [(pose(0.0), Look(0, 0))]
    cands, _ = b.visit(1, 0)
    two = [cands[0], (500, pose(0.1), Look(0, 1), K)]
    b.frames[500] = (0, 1)
    params = UpdateParams(replace=ReplaceParams(max_per_place=1))
    d1, d2 = plan_replacements(keyframes(nodes), two, [], b.score, params, set())  # no held-out frames at all
    assert d1.outcome is Outcome.DENSE and d1.replaced == ()  # the stale keyframe fills the place
    d1, d2 = plan_replacements(keyframes(nodes), two, [], b.score, UpdateParams(), set())
    assert d1.outcome is Outcome.NO_EVIDENCE and d2.outcome is Outcome.DENSE and not d1.replaced


def test_a_new_place_candidate_replaces_a_stale_keyframe_it_explains_and_is_kept() -> None:
    b = Building(1)
    nodes = [(pose(0.0), Look(0, 0))]
    _, probes = b.visit(1, 0)  # place 0 changed (epoch 1); its frames lie around x = 0
    fresh = [(700, pose(1.0), Look(0, 1), K)]  # 1 m off: no keyframe covers it, within match_radius_m
    d, = plan_replacements(keyframes(nodes), fresh, probes, b.score, PARAMS, set(), new_places=True)
    assert d.outcome is Outcome.REPLACED and d.replaced == (0,)
    unrelated = [(700, pose(1.0), Look(5, 1), K)]  # explains nothing of place 0: kept, replaces nothing
    d, = plan_replacements(keyframes(nodes), unrelated, probes, b.score, PARAMS, set(), new_places=True)
    assert d.outcome is Outcome.ADDED and d.replaced == ()
