"""Surface appearance of a world, baked once into texture arrays for the renderer.

Surfaces come from `litevloc.sim.materials` (wall materials, furniture fronts, the
photographs of the aliased appearance) and `litevloc.sim.pictures` (the varied appearance's
generated posters, prints, notice boards, plates and signs). A world with the aliased
appearance bakes exactly as the first simulator did (same stream, same order).

Baked arrays (uint8 RGB unless noted):

* `atlas`: (rows, cols, 3) wall/box face textures side by side; row r is height
  z = wall_height - (r + 0.5) / ppm, a face's column offset + s * ppm is its texture
  coordinate s (metres, left to right as seen from the front). Mip levels 1..3 halve it.
* `floor`, `ceiling`: world-aligned maps over `World.bounds`, row = y, col = x.
* `top_tile`: a wood tile for box tops, with per-box tint `top_color` (N, 3) float32.
"""

from __future__ import annotations

import colorsys
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from litevloc.sim.decor import door_faces
from litevloc.sim.elements import Face, Poster, s_increasing
from litevloc.sim.materials import (
    blur,
    books,
    cabinet,
    clutter_front,
    floor_patch,
    load_image,
    material,
    pastel,
    photo_poster,
    room_material,
    tile,
    tint,
    wall_surface,
)
from litevloc.sim.pictures import picture
from litevloc.sim.world import World

MIP_LEVELS = 4
Look = tuple[str, tuple[float, float, float], float]  # material, colour, pattern scale


@dataclass
class BakedTextures:
    """Texture arrays of one world (see module docstring)."""

    ppm: float
    atlas: list[NDArray[np.uint8]]  # mip levels 0..MIP_LEVELS-1
    face_offset: NDArray[np.float64]  # (F,) atlas column of s = 0 per face
    floor: NDArray[np.uint8]
    floor_ppm: float
    ceiling: NDArray[np.uint8]
    ceiling_ppm: float
    top_tile: NDArray[np.float32]  # (n, n, 3) 0..1
    top_ppm: float
    top_color: NDArray[np.float32]  # (B, 3) 0..255

    @property
    def nbytes(self) -> int:
        return int(sum(a.nbytes for a in self.atlas) + self.floor.nbytes + self.ceiling.nbytes)


def _looks(world: World, rng: np.random.Generator) -> dict[int, Look]:
    """Per-region wall look: material, colour and pattern scale."""
    looks: dict[int, Look] = {}
    for r in world.regions.values():
        colour = pastel(rng)
        if r.material == "brick":  # red-brown to grey bricks
            rr, gg, bb = colorsys.hsv_to_rgb(rng.uniform(0.0, 0.08), rng.uniform(0.1, 0.5), rng.uniform(0.6, 0.85))
            colour = (rr * 255, gg * 255, bb * 255)
        looks[r.label] = (r.material, colour, float(rng.uniform(0.8, 1.25)))
    return looks


def _room_tiles(world: World, looks: dict[int, Look]) -> dict[int, NDArray[np.float32]]:
    """Varied appearance: each region's own plaster / wallpaper / panel tile (its own stream)."""
    out = {}
    for label, (mat, colour, _scale) in looks.items():
        t = room_material(mat, world.spec.texels_per_m, np.random.default_rng([world.spec.seed, 8, label]), colour)
        if t is not None:
            out[label] = t
    return out


def _face_world_start(f: Face) -> float:
    """World coordinate (m) along a face where its s = 0 lies (room patterns continue across faces)."""
    return f.lo if s_increasing(f) else -f.hi


def _wall_patch(world: World, fi: int, rows: int, w: int, looks: dict[int, Look],
                tiles: dict[int, NDArray[np.float32]], rng: np.random.Generator) -> NDArray[np.float32]:
    ppm, f, seed = world.spec.texels_per_m, world.faces[fi], world.spec.seed
    mat, colour, scale = looks.get(f.region, ("painted", (170.0, 170.0, 170.0), 1.0))
    reg = world.regions.get(f.region)
    if reg is not None and reg.kind == "corridor" and rng.random() < 0.5:
        # long corridors: wall sections vary, so places along them differ
        mat = str(rng.choice(["painted", "plaster", "panel", "painted"]))
        colour = pastel(rng)
    own = None
    if world.spec.appearance == "varied":
        own = wall_surface(mat, rows, w, ppm, np.random.default_rng([seed, 8, f.region]),
                           np.random.default_rng([seed, 12, fi]), colour)
        if own is None and mat == "wallpaper" and f.region in tiles:
            own = tile(np.clip(tiles[f.region], 0, 255).astype(np.uint8), rows, w, 1.0, 0.0,
                       _face_world_start(f) * ppm)
    patch = own if own is not None else material(mat, rows, w, ppm, rng, colour, scale)
    z_row = world.wall_height - (np.arange(rows) + 0.5) / ppm
    patch[z_row < 0.08] = np.array(colour, np.float32) * 0.45  # skirting
    return patch


def _box_patch(world: World, f: Face, rows: int, w: int, rng: np.random.Generator,
               palettes: dict[int, list[tuple[float, float, float]]], boxes: NDArray[np.float64],
               kinds: list[str]) -> NDArray[np.float32]:
    """Texture of box face `f` (`f.box` indexes `boxes` and `kinds`)."""
    ppm, H = world.spec.texels_per_m, world.wall_height
    kind = kinds[f.box]
    patch = np.zeros((rows, w, 3), np.float32)
    r0 = int(np.floor((H - f.height) * ppm))
    bh = rows - r0
    if kind == "shelf" and rng.random() < 0.85:
        sub = books(bh, w, ppm, rng)
    elif kind == "pillar":
        sub = material("plaster", bh, w, ppm, rng, (175, 175, 170), 1.0)
    elif kind == "door":
        sub = material("panel", bh, w, ppm, rng, pastel(rng, (0.1, 0.4), (0.45, 0.8)), 1.0)
    elif kind in ("bin", "plant", "stool", "crate"):
        sub = clutter_front(kind, bh, w, ppm, rng)
    elif world.spec.appearance == "varied":  # the room's own furniture colours
        b = boxes[f.box]
        pal = palettes.get(world.region_at(np.array([(b[0] + b[2]) / 2, (b[1] + b[3]) / 2])), [(150.0,) * 3])
        sub = cabinet(bh, w, ppm, rng, pal[f.box % len(pal)])
    else:
        sub = cabinet(bh, w, ppm, rng, pastel(rng, (0.1, 0.5), (0.35, 0.8)))
    patch[r0:] = sub
    return patch


def _picture(p: Poster, h: int, w: int, rng: np.random.Generator) -> NDArray[np.float32]:
    if p.kind == "photo":
        return photo_poster(p.image, h, w, rng)
    return picture(p.kind, p.design, p.text, h, w)


def _door_frames(world: World, atlas: NDArray[np.float32], offsets: NDArray[np.float64]) -> None:
    """Varied appearance: a frame strip (one colour per building, as real doors repeat) on
    each wall face beside a door, up to the door's height."""
    rng = np.random.default_rng([world.spec.seed, 10])
    colour = np.array(pastel(rng, (0.0, 0.5), (0.25, 0.9)), np.float32)
    ppm, H = world.spec.texels_per_m, world.wall_height
    strip, r0 = max(2, int(0.07 * ppm)), int((H - min(2.1, H - 0.1)) * ppm)
    for door in world.doors:
        for region in door[:2]:
            for fi, s_end in door_faces(door, region, world.faces):
                c = int(offsets[fi] + s_end * ppm)
                c0, c1 = (c - strip, c) if s_end > 0 else (c, c + strip)
                atlas[r0:, max(c0, int(offsets[fi])) : c1] = colour
                atlas[r0 : r0 + strip, max(c0, int(offsets[fi])) : c1] = colour * 0.8


def _widths(faces: list[Face], ppm: float) -> tuple[list[int], NDArray[np.float64]]:
    widths = [int(np.ceil((f.hi - f.lo) * ppm)) + 2 for f in faces]
    return widths, np.concatenate([[0], np.cumsum(widths)[:-1]]).astype(np.float64)


def _face_patches(world: World, faces: list[Face], boxes: NDArray[np.float64], kinds: list[str],
                  rng: np.random.Generator, palettes: dict[int, list[tuple[float, float, float]]],
                  looks: dict[int, Look], tiles: dict[int, NDArray[np.float32]]) -> NDArray[np.float32]:
    """(rows, sum of widths, 3) atlas of `faces` (walls of `world`, boxes of `boxes`), in order."""
    ppm, H = world.spec.texels_per_m, world.wall_height
    rows = int(np.ceil(H * ppm))
    widths, offsets = _widths(faces, ppm)
    atlas = np.zeros((rows, int(sum(widths)), 3), np.float32)
    z_row = H - (np.arange(rows) + 0.5) / ppm  # height of each atlas row
    for fi, f in enumerate(faces):
        w, o = widths[fi], int(offsets[fi])
        patch = (_wall_patch(world, fi, rows, w, looks, tiles, rng) if f.kind == "wall"
                 else _box_patch(world, f, rows, w, rng, palettes, boxes, kinds))
        # soft shading near floor and ceiling
        patch *= (0.8 + 0.2 * np.clip(z_row / 0.5, 0, 1) * np.clip((H - z_row) / 0.4, 0, 1))[:, None, None]
        atlas[:, o : o + w] = patch
    return atlas


def _changed_atlas(world: World, generated: NDArray[np.float32], palettes: dict[int, list[tuple[float, float, float]]],
                   rng: np.random.Generator) -> NDArray[np.float32]:
    """The atlas of a changed world's faces from the generated building's: walls and the boxes
    that stay (moved or not) keep their columns, new boxes (source -1) are baked from `rng`."""
    ppm = world.spec.texels_per_m
    gen_widths, gen_offsets = _widths(world.generated.faces, ppm)
    widths, offsets = _widths(world.faces, ppm)
    n_walls = sum(f.kind == "wall" for f in world.faces)
    atlas = np.zeros((generated.shape[0], int(sum(widths)), 3), np.float32)
    for fi, f in enumerate(world.faces):
        w, o = widths[fi], int(offsets[fi])
        src = fi if f.kind == "wall" else -1
        if f.kind == "box" and world.box_source[f.box] >= 0:
            src = n_walls + 4 * int(world.box_source[f.box]) + (fi - n_walls) % 4
        if src >= 0:
            atlas[:, o : o + w] = generated[:, int(gen_offsets[src]) : int(gen_offsets[src]) + gen_widths[src]]
        else:
            atlas[:, o : o + w] = _face_patches(world, [f], world.boxes, world.box_kinds, rng, palettes, {}, {})
    return atlas


def _face_regions(world: World) -> list[int]:
    """Region each face is lit in: a wall's own, a box face's the region under its box."""
    centres = (world.boxes[:, :2] + world.boxes[:, 2:4]) / 2
    return [f.region if f.kind == "wall" else world.region_at(centres[f.box]) for f in world.faces]


def _relit(img: NDArray[np.uint8], world: World) -> NDArray[np.uint8]:
    """A floor or ceiling map (over `world.bounds`) under the world's lighting change."""
    assert world.lighting is not None
    lab = cv2.resize(world.labels.astype(np.float32), (img.shape[1], img.shape[0]),
                     interpolation=cv2.INTER_NEAREST).astype(np.int32)
    return np.clip(img * world.lighting.region_gain(lab)[..., None], 0, 255).astype(np.uint8)


def bake(world: World) -> BakedTextures:
    """Bake every face, the floor and the ceiling of `world` (deterministic in its seed).

    The building as generated (`world.generated`) is baked from the seed's stream; a changed
    world then takes the columns of what stayed and bakes its new boxes from a stream of their
    own, so every random draw of the generated building stays where it was."""
    rng = np.random.default_rng([world.spec.seed, 7])
    extra = np.random.default_rng([world.spec.seed, 7, 1])
    ppm = world.spec.texels_per_m
    H = world.wall_height
    gen = world.generated
    widths, offsets = _widths(world.faces, ppm)
    looks = _looks(world, rng)
    varied = world.spec.appearance == "varied"
    tiles = _room_tiles(world, looks) if varied else {}
    palettes = {label: [pastel(np.random.default_rng([world.spec.seed, 9, label, k]), (0.1, 0.6), (0.3, 0.85))
                        for k in range(2)] for label in world.regions} if varied else {}
    atlas = _face_patches(world, gen.faces, gen.boxes, gen.box_kinds, rng, palettes, looks, tiles)
    if not np.array_equal(world.box_source, np.arange(len(gen.boxes))):
        atlas = _changed_atlas(world, atlas, palettes, extra)
    if varied:
        _door_frames(world, atlas, offsets)
    for p in world.posters:
        o = int(offsets[p.face])
        c0, c1 = o + int(p.s0 * ppm), o + int((p.s0 + p.width) * ppm)
        r0, r1 = int((H - p.z0 - p.height) * ppm), int((H - p.z0) * ppm)
        atlas[r0:r1, c0:c1] = _picture(p, r1 - r0, c1 - c0, rng)
    # orientation shading: faces facing +-x slightly darker than +-y (one light direction)
    shade = np.ones(atlas.shape[1], np.float32)
    gains = world.lighting.face_gains(world.faces, _face_regions(world)) if world.lighting is not None else None
    for fi, f in enumerate(world.faces):
        o = int(offsets[fi])
        shade[o : o + widths[fi]] = (0.86 if f.normal > 0 else 0.94) if f.axis == 0 else (1.0 if f.normal > 0 else 0.9)
        if gains is not None:
            shade[o : o + widths[fi]] *= gains[fi]
    atlas *= shade[None, :, None]
    atlas_u8 = np.clip(atlas, 0, 255).astype(np.uint8)
    mips = [atlas_u8]
    for _ in range(1, MIP_LEVELS):
        mips.append(np.asarray(cv2.pyrDown(mips[-1]), dtype=np.uint8))
    floor, fppm = _bake_floor(world, rng)
    ceiling, cppm = _bake_ceiling(world, rng)
    top_ppm = 64.0
    grain = tile(load_image("gravel.png"), 128, 128, 0.5)
    top_tile = cv2.GaussianBlur(grain, (0, 0), sigmaX=6, sigmaY=0.7).mean(axis=2, keepdims=True)
    top_tile = (0.75 + 0.25 * (top_tile - top_tile.mean()) / max(float(top_tile.std()), 1e-3) * 0.5).astype(
        np.float32)
    gen_top = np.array([pastel(rng, (0.2, 0.5), (0.4, 0.8)) for _ in range(len(gen.boxes))],
                       np.float32).reshape(-1, 3)
    top_color = np.array([gen_top[s] if s >= 0 else pastel(extra, (0.2, 0.5), (0.4, 0.8)) for s in world.box_source],
                         np.float32).reshape(-1, 3)
    if world.lighting is not None:
        floor, ceiling = _relit(floor, world), _relit(ceiling, world)
        lamps, exposure = world.lighting.lamps, world.lighting.exposure
        centres = (world.boxes[:, :2] + world.boxes[:, 2:4]) / 2
        top_color *= np.array([lamps.get(world.region_at(c), 1.0) * exposure for c in centres],
                              np.float32).reshape(-1, 1)
    return BakedTextures(ppm, mips, offsets, floor, fppm, ceiling, cppm, np.repeat(top_tile, 3, axis=2), top_ppm,
                         top_color)


def _bake_floor(world: World, rng: np.random.Generator) -> tuple[NDArray[np.uint8], float]:
    fppm = 32.0
    x0, y0, x1, y1 = world.bounds
    W, Hh = int(np.ceil((x1 - x0) * fppm)), int(np.ceil((y1 - y0) * fppm))
    out = np.zeros((Hh, W, 3), np.float32)
    lab = cv2.resize(
        world.labels.astype(np.float32), (W, Hh), interpolation=cv2.INTER_NEAREST
    ).astype(np.int32)
    for r in world.regions.values():
        bx0, by0, bx1, by1 = (int(v * fppm) for v in r.bbox)
        h, w = by1 - by0, bx1 - bx0
        kind = (
            "tiles"
            if r.kind == "corridor"
            else str(rng.choice(["carpet", "wood", "tiles", "carpet"]))
        )
        if world.spec.appearance == "varied":
            p = floor_patch(kind, h, w, fppm, np.random.default_rng([world.spec.seed, 11, r.label]))
        elif kind == "carpet":
            p = tint(
                tile(load_image("gravel.png"), h, w, 512 / (1.5 * fppm), rng.uniform(0, 512)),
                pastel(rng, (0.15, 0.5), (0.3, 0.6)),
                0.7,
            )
        elif kind == "wood":
            grain = tile(load_image("gravel.png"), h, w, 0.6, rng.uniform(0, 512))
            p = tint(
                blur(grain, (0, 0), sigmaX=5, sigmaY=0.5),
                pastel(rng, (0.35, 0.55), (0.45, 0.7)),
                0.8,
            )
            plank = int(0.18 * fppm)
            p[(np.arange(h) % plank) == 0] *= 0.6
        else:
            base = np.array(pastel(rng, (0.0, 0.15), (0.6, 0.85)), np.float32)
            p = np.empty((h, w, 3), np.float32)
            p[:] = base
            p += rng.normal(0, 3, (h, w, 1)).astype(np.float32)
            t = int(0.6 * fppm)
            p[(np.arange(h) % t) == 0] *= 0.7
            p[:, (np.arange(w) % t) == 0] *= 0.7
        m = lab[by0:by1, bx0:bx1] == r.label
        out[by0:by1, bx0:bx1][m] = p[m]
    return np.clip(out, 0, 255).astype(np.uint8), fppm


def _bake_ceiling(world: World, rng: np.random.Generator) -> tuple[NDArray[np.uint8], float]:
    cppm = 16.0
    x0, y0, x1, y1 = world.bounds
    W, Hh = int(np.ceil((x1 - x0) * cppm)), int(np.ceil((y1 - y0) * cppm))
    out = np.full((Hh, W, 3), 215.0, np.float32)
    out += rng.normal(0, 2, (Hh, W, 1)).astype(np.float32)
    t = int(0.6 * cppm)
    out[(np.arange(Hh) % t) == 0] *= 0.85
    out[:, (np.arange(W) % t) == 0] *= 0.85
    step = int(2.4 * cppm)
    for yy in range(step // 2, Hh - t, step):
        for xx in range(step // 2, W - 2 * t, step):
            out[yy : yy + t, xx : xx + 2 * t] = 250
    return np.clip(out, 0, 255).astype(np.uint8), cppm
