"""Hubness of map keyframes in place recognition, and GL's ranking with its penalty."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from litevloc.pipelines.localization.hubness import BLOCK, hubness
from litevloc.pipelines.localization.query import StageTimer
from litevloc.pipelines.localization.vloc import VisualLocalizer
from tests.pipelines.localization.test_vloc import IMG, PARAMS, K, Scene, make_map, pose


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def test_a_view_like_many_other_places_is_the_hub_and_its_own_place_does_not_count() -> None:
    rng = np.random.default_rng(0)
    places = _unit(rng.normal(size=(6, 32)))
    hub = _unit(places.sum(0, keepdims=True))  # resembles every place a little
    twin = _unit(places[:1] + 0.01 * rng.normal(size=(1, 32)))  # place 0 seen again, 0.5 m away
    vpr = np.vstack([places, hub, twin])
    pos = np.vstack([np.c_[np.arange(6) * 10.0, np.zeros((6, 2))], [[100.0, 0, 0]], [[0.5, 0, 0]]])
    h = hubness(vpr, pos, k=3, exclude_m=3.0)
    assert int(np.argmax(h)) == 6 and h[6] > 0.3
    assert h[7] < h[6] and h[0] < h[6]  # place 0 and its twin: similar to each other only, same place
    assert hubness(vpr, pos, k=3, exclude_m=0.0)[7] > h[7]  # counting its own place would raise it
    assert np.allclose(hubness(vpr, np.zeros((8, 3)), 3, 3.0), 0.0)  # no other place: 0
    big = _unit(rng.normal(size=(BLOCK + 7, 8)))
    far = np.c_[np.arange(BLOCK + 7) * 10.0, np.zeros((BLOCK + 7, 2))]
    sims = big @ big.T
    np.fill_diagonal(sims, -np.inf)
    assert np.allclose(hubness(big, far, 2, 3.0), np.sort(sims, axis=1)[:, -2:].mean(1), atol=1e-5)  # across blocks


def test_gl_ranks_a_hub_below_the_right_keyframe_under_the_hub_penalty() -> None:
    m = make_map([0.0, 10.0, 20.0, 30.0])
    hub = np.full(4, 0.5, np.float32)  # node 3's descriptor resembles every keyframe
    m.vpr[3] = hub / np.linalg.norm(hub)
    s = Scene(m)
    gs = VisualLocalizer(m, PARAMS, s.extract, s.describe, s.match).global_search
    depth = s.look(pose(10.0), vpr_best=1)
    s.vpr = np.array([0.3, 0.6, 0.3, 0.3], np.float32)  # the right keyframe (1) below the hub by raw similarity
    q, desc = gs.verifier.query(IMG, depth, K, PARAMS, StageTimer())
    sims = m.vpr @ desc
    assert int(np.argmax(sims)) == 3
    p0 = replace(PARAMS, global_search=replace(PARAMS.global_search, rerank=False))
    assert int(gs.candidates(p0, sims, q)[0]) == 3
    on = replace(p0, global_search=replace(p0.global_search, hub_penalty=1.0, hub_neighbours=2))
    assert int(gs.candidates(on, sims, q)[0]) == 1
