"""Covisibility graph: KD-tree candidate pairs and pose-guided matching on real 7-Scenes frames."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from litevloc.base import geometry as g
from litevloc.base.params.mapping import CovisibilityParams
from litevloc.pipelines.topomap.graphs import covisibility_candidates

from .helpers import build_7scenes, seven_scenes_mapping


def test_candidates_match_the_brute_force_gates() -> None:
    rng = np.random.default_rng(3)
    T = np.stack([g.make_T(g.so3_exp(rng.normal(size=3)), rng.uniform(-5, 5, 3)) for _ in range(150)])
    p = CovisibilityParams(max_distance_m=3.0, max_angle_deg=60.0)
    brute = [(i, j) for i in range(150) for j in range(i + 1, 150)
             if np.linalg.norm(T[i, :3, 3] - T[j, :3, 3]) <= 3.0
             and T[i, :3, 2] @ T[j, :3, 2] >= np.cos(np.radians(60.0))]
    assert covisibility_candidates(T, p) == brute and len(brute) > 20
    assert covisibility_candidates(T[:1], p) == []


def test_bad_matching_option_is_an_error() -> None:
    with pytest.raises(ValueError, match="matching"):
        CovisibilityParams(matching="sift")  # type: ignore[arg-type]


def test_guided_covisibility_finds_the_model_matchers_edges(seven_scenes_dir: Path) -> None:
    """Same keyframes, covisibility by the matcher (ORB cross-check here) vs guided by the
    mapping poses (real ground truth, off by up to ~2.5 deg between keyframes): the guided
    graph keeps most edges (27 of 31 when written) and invents almost none."""
    base = seven_scenes_mapping(budget=None)
    model = replace(base, covisibility=replace(base.covisibility, matching="model"))
    guided = replace(base, covisibility=replace(base.covisibility, matching="guided"))
    a = build_7scenes(seven_scenes_dir, "0:200:4", model).finish()
    b = build_7scenes(seven_scenes_dir, "0:200:4", guided).finish()
    np.testing.assert_array_equal(a.T_map_camera, b.T_map_camera)  # the same keyframes
    ea = {tuple(e) for e in a.covis_edges.tolist()}
    eb = {tuple(e) for e in b.covis_edges.tolist()}
    assert len(ea) >= 10
    assert len(ea & eb) >= 0.8 * len(ea), (len(ea), len(eb), len(ea & eb))
    assert len(eb - ea) <= 0.1 * len(ea), (len(ea), len(eb), len(eb - ea))
    pairs = set(covisibility_candidates(a.T_map_camera, base.covisibility))
    assert eb <= pairs
