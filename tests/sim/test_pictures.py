"""Pictures of a varied building do not repeat unless the world file asks: every picture has a
design of its own (plates and signs their own text), different designs draw different pixels,
and the baked walls show what the designs say; with `repeated_pictures` some prints hang twice."""

from __future__ import annotations

import itertools

import cv2
import numpy as np
import pytest

from litevloc.sim.pictures import picture
from litevloc.sim.render import baked_textures
from litevloc.sim.world import World, load_world


def signature(rgb: np.ndarray) -> np.ndarray:
    """Zero-mean unit-norm colour 24 x 24 thumbnail of a picture's inner 80 % (frames look alike)."""
    g = np.asarray(rgb, np.float32)
    h, w = g.shape[:2]
    v = cv2.resize(g[h // 10 : h - h // 10, w // 10 : w - w // 10], (24, 24), interpolation=cv2.INTER_AREA).ravel()
    v -= v.mean()
    return v / max(float(np.linalg.norm(v)), 1e-6)


def atlas_crops(world: World) -> list[np.ndarray]:
    """Each picture's pixels as baked into the wall atlas (mip 0)."""
    tex = baked_textures(world)
    ppm, H = tex.ppm, world.wall_height
    out = []
    for p in world.posters:
        o = int(tex.face_offset[p.face])
        r0, r1 = int((H - p.z0 - p.height) * ppm), int((H - p.z0) * ppm)
        out.append(tex.atlas[0][r0:r1, o + int(p.s0 * ppm) : o + int((p.s0 + p.width) * ppm)])
    return out


@pytest.mark.parametrize("seed", [3])
def test_no_picture_repeats_within_a_building(seed: int) -> None:
    world = load_world("floor", seed=seed)
    kinds = {p.kind for p in world.posters}
    assert {"poster", "print", "notice", "plate", "sign"} <= kinds and "photo" not in kinds
    keys = [p.key for p in world.posters]
    assert len(set(keys)) == len(keys)  # no two pictures share kind, design and text
    content = [p for p in world.posters if p.kind in ("poster", "print", "notice")]
    sigs = [signature(picture(p.kind, p.design, p.text, 60, 60)) for p in content]
    worst = max(float(a @ b) for a, b in itertools.combinations(sigs, 2))
    assert worst < 0.9, worst  # different designs draw different pictures
    for p, crop in zip(world.posters, atlas_crops(world), strict=True):  # the walls show the designs
        drawn = picture(p.kind, p.design, p.text, crop.shape[0], crop.shape[1])
        assert float(signature(drawn) @ signature(crop)) > 0.97


def test_repetition_only_where_the_world_file_asks() -> None:
    world = load_world("floor", seed=3, repeated_pictures=0.5)
    by_key: dict[tuple[object, ...], list[tuple[float, float]]] = {}
    for p in world.posters:
        by_key.setdefault(p.key, []).append((p.width, p.height))
    copies = [sizes for sizes in by_key.values() if len(sizes) > 1]
    assert len(copies) >= 5 and all(len(set(sizes)) == 1 for sizes in copies)  # the same print, same size
    aliased = load_world("floor", seed=3, appearance="aliased")  # the first simulator's 11 photographs
    photos = [p.image for p in aliased.posters]
    assert len(set(photos)) <= 11 < len(photos)
