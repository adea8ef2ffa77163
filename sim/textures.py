"""Surface appearance of a world, baked once into texture arrays for the renderer.

Photographs and material textures come from the data folder that the scikit-image
package ships (read with OpenCV by path; nothing is downloaded). Only files whose
licence the package documents as CC0 / public domain are used:

* materials: brick.png, gravel.png, grass.png (CC0Textures.com, CC0);
* pictures ("posters"): astronaut.png, rocket.jpg, hubble_deep_field.jpg (NASA /
  SpaceX, public domain), camera.png (CC0, L. Varshney), chelsea.png (CC0,
  S. van der Walt), coffee.png (CC0, R. Michetti), coins.png (public domain),
  clock_motion.png (public domain, S. van der Walt), text.png (public domain),
  retina.jpg (CC0), cell.png (CC0).

Baked arrays (uint8 RGB unless noted):

* `atlas`: (rows, cols, 3) wall/box face textures side by side; row r is height
  z = wall_height - (r + 0.5) / ppm, a face's column offset + s * ppm is its texture
  coordinate s (metres, left to right as seen from the front). Mip levels 1..3 halve it.
* `floor`, `ceiling`: world-aligned maps over `World.bounds`, row = y, col = x.
* `top_tile`: a wood tile for box tops, with per-box tint `top_color` (N, 3) float32.
"""

from __future__ import annotations

import colorsys
import importlib.util
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np
from numpy.typing import NDArray

from litevloc.base.errors import LiteVLocError

if TYPE_CHECKING:
    from litevloc.sim.world import Face, World

POSTER_IMAGES = (
    "astronaut.png",
    "rocket.jpg",
    "hubble_deep_field.jpg",
    "camera.png",
    "chelsea.png",
    "coffee.png",
    "coins.png",
    "clock_motion.png",
    "text.png",
    "retina.jpg",
    "cell.png",
)
MATERIAL_IMAGES = ("brick.png", "gravel.png", "grass.png")
MIP_LEVELS = 4


class TextureError(LiteVLocError, RuntimeError):
    """The scikit-image data folder (texture source) is missing or a file is unreadable."""


def data_dir() -> Path:
    """scikit-image's shipped data folder."""
    spec = importlib.util.find_spec("skimage")
    if spec is None or not spec.submodule_search_locations:
        raise TextureError(
            "scikit-image is not installed; the simulator takes its textures from its data folder"
        )
    return Path(next(iter(spec.submodule_search_locations))) / "data"


@lru_cache(maxsize=32)
def load_image(name: str) -> NDArray[np.uint8]:
    """HxWx3 uint8 RGB of a file in scikit-image's data folder."""
    path = data_dir() / name
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise TextureError(f"cannot read texture {path}")
    img = np.ascontiguousarray(img[:, :, ::-1])
    img.setflags(write=False)
    return np.asarray(img, dtype=np.uint8)


def tile(
    img: NDArray[np.uint8], h: int, w: int, texel: float, oy: float = 0.0, ox: float = 0.0
) -> NDArray[np.float32]:
    """Tile `img` over an h x w patch, `texel` image pixels per patch pixel; float32 0..255."""
    ih, iw = img.shape[:2]
    rows = ((np.arange(h) * texel + oy) % ih).astype(np.intp)
    cols = ((np.arange(w) * texel + ox) % iw).astype(np.intp)
    return img[np.ix_(rows, cols)].astype(np.float32)


def _blur(
    img: NDArray[np.float32], ksize: tuple[int, int], sigmaX: float, sigmaY: float = 0.0
) -> NDArray[np.float32]:
    return np.asarray(cv2.GaussianBlur(img, ksize, sigmaX=sigmaX, sigmaY=sigmaY), dtype=np.float32)


def tint(
    patch: NDArray[np.float32], rgb: tuple[float, float, float], contrast: float = 1.0
) -> NDArray[np.float32]:
    """Grey-level texture -> coloured: mean-preserving contrast, multiplied by a colour."""
    g = patch.mean(axis=2, keepdims=True)
    m = float(g.mean())
    g = m + (g - m) * contrast
    return np.clip(g / max(m, 1.0) * np.array(rgb, np.float32), 0, 255)


def _pastel(
    rng: np.random.Generator,
    sat: tuple[float, float] = (0.05, 0.3),
    val: tuple[float, float] = (0.65, 0.92),
) -> tuple[float, float, float]:
    r, g, b = colorsys.hsv_to_rgb(rng.random(), rng.uniform(*sat), rng.uniform(*val))
    return (r * 255, g * 255, b * 255)


def hue_shift(img: NDArray[np.uint8], shift_deg: float, sat: float = 1.0) -> NDArray[np.uint8]:
    hsv = cv2.cvtColor(img, cv2.COLOR_RGB2HSV).astype(np.int32)
    hsv[..., 0] = (hsv[..., 0] + int(shift_deg / 2)) % 180
    hsv[..., 1] = np.clip(hsv[..., 1] * sat, 0, 255)
    return np.asarray(cv2.cvtColor(hsv.astype(np.uint8), cv2.COLOR_HSV2RGB), dtype=np.uint8)


def _material(
    kind: str,
    h: int,
    w: int,
    ppm: float,
    rng: np.random.Generator,
    colour: tuple[float, float, float],
    scale: float,
) -> NDArray[np.float32]:
    """A wall material patch h x w (atlas pixels at `ppm` per metre)."""
    if kind == "painted":
        base = np.empty((h, w, 3), np.float32)
        base[:] = colour
        base += rng.normal(0, 1.5, (h, w, 1)).astype(np.float32)
        return base
    if kind == "brick":
        # brick.png spans about 1.6 m of wall
        return tint(
            tile(
                load_image("brick.png"),
                h,
                w,
                512 / (1.6 * scale * ppm),
                rng.uniform(0, 512),
                rng.uniform(0, 512),
            ),
            colour,
            0.8,
        )
    if kind == "plaster":
        p = tile(
            load_image("gravel.png"),
            h,
            w,
            512 / (2.0 * scale * ppm),
            rng.uniform(0, 512),
            rng.uniform(0, 512),
        )
        return tint(_blur(p, (0, 0), 2.5), colour, 0.35)
    if kind == "wallpaper":
        return tint(
            tile(
                load_image("grass.png"),
                h,
                w,
                512 / (1.2 * scale * ppm),
                rng.uniform(0, 512),
                rng.uniform(0, 512),
            ),
            colour,
            0.8,
        )
    if kind == "panel":
        grain = tile(load_image("gravel.png"), h, w, 0.5, rng.uniform(0, 512), rng.uniform(0, 512))
        wood = tint(_blur(grain, (0, 0), sigmaX=0.5, sigmaY=6), (150, 105, 70), 0.8)
        plank = max(4, int(0.3 * ppm * scale))
        cols = np.arange(w) % plank
        wood[:, cols == 0] *= 0.55
        return wood
    raise ValueError(f"unknown material {kind!r}")


def _books(h: int, w: int, ppm: float, rng: np.random.Generator) -> NDArray[np.float32]:
    """Front of a shelf: wooden frame, shelf boards every ~0.38 m, rows of coloured spines."""
    out = np.empty((h, w, 3), np.float32)
    out[:] = (120, 85, 55)
    shelf = int(0.38 * ppm)
    board = max(2, int(0.03 * ppm))
    frame = max(2, int(0.04 * ppm))
    for top in range(frame, h - board, shelf):
        x = frame
        bottom = min(top + shelf - board, h - frame)
        while x < w - frame:
            bw = int(rng.uniform(0.02, 0.06) * ppm) + 1
            bh = int(rng.uniform(0.55, 0.95) * (bottom - top))
            if rng.random() < 0.12:
                x += bw * 2
                continue
            col = colorsys.hsv_to_rgb(rng.random(), rng.uniform(0.3, 0.9), rng.uniform(0.25, 0.9))
            out[bottom - bh : bottom, x : min(x + bw, w - frame)] = np.array(col, np.float32) * 255
            out[bottom - bh : bottom, x] *= 0.6
            x += bw
        out[bottom : bottom + board] = (100, 70, 45)
    out[:, :frame] = out[:, -frame:] = (95, 65, 40)
    return out


def _cabinet(
    h: int, w: int, ppm: float, rng: np.random.Generator, colour: tuple[float, float, float]
) -> NDArray[np.float32]:
    grain = tile(load_image("gravel.png"), h, w, 0.4, rng.uniform(0, 512), rng.uniform(0, 512))
    out = tint(_blur(grain, (0, 0), 2.0), colour, 0.4)
    n_draw = int(rng.integers(2, 5))
    for k in range(1, n_draw):
        r = int(k * h / n_draw)
        out[max(r - 1, 0) : r + 1] *= 0.5
    n_door = max(1, int(w / (0.5 * ppm)))
    for k in range(1, n_door):
        c = int(k * w / n_door)
        out[:, max(c - 1, 0) : c + 1] *= 0.5
    for k in range(n_draw):
        r = int((k + 0.5) * h / n_draw)
        for m in range(n_door):
            c = int((m + 0.5) * w / n_door)
            out[r - 2 : r + 2, c - int(0.06 * ppm) : c + int(0.06 * ppm)] = (60, 60, 65)
    return out


def _poster(name: str, h: int, w: int, rng: np.random.Generator) -> NDArray[np.float32]:
    img = load_image(name)
    ih, iw = img.shape[:2]
    # random crop with the poster's aspect ratio (same photo, different framing per copy)
    ar = w / max(h, 1)
    ch = int(min(ih, iw / ar) * rng.uniform(0.6, 1.0))
    cw = int(ch * ar)
    y0, x0 = int(rng.integers(0, ih - ch + 1)), int(rng.integers(0, iw - cw + 1))
    crop = img[y0 : y0 + ch, x0 : x0 + cw]
    if rng.random() < 0.5:
        crop = hue_shift(np.ascontiguousarray(crop), rng.uniform(-40, 40), rng.uniform(0.7, 1.2))
    out = cv2.resize(crop, (w, h), interpolation=cv2.INTER_AREA).astype(np.float32)
    f = max(2, int(0.03 * max(h, w)))
    out[:f], out[-f:], out[:, :f], out[:, -f:] = 30, 30, 30, 30
    return out


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


def bake(world: World) -> BakedTextures:
    """Bake every face, the floor and the ceiling of `world` (deterministic in its seed)."""
    rng = np.random.default_rng([world.spec.seed, 7])
    ppm = world.spec.texels_per_m
    H = world.wall_height
    rows = int(np.ceil(H * ppm))
    widths = [int(np.ceil((f.hi - f.lo) * ppm)) + 2 for f in world.faces]
    offsets = np.concatenate([[0], np.cumsum(widths)[:-1]]).astype(np.float64)
    atlas = np.zeros((rows, int(sum(widths)), 3), np.float32)
    # per-region wall look
    looks: dict[int, tuple[str, tuple[float, float, float], float]] = {}
    for r in world.regions.values():
        colour = _pastel(rng)
        if r.material == "brick":  # red-brown to grey bricks
            rr, gg, bb = colorsys.hsv_to_rgb(
                rng.uniform(0.0, 0.08), rng.uniform(0.1, 0.5), rng.uniform(0.6, 0.85)
            )
            colour = (rr * 255, gg * 255, bb * 255)
        looks[r.label] = (r.material, colour, float(rng.uniform(0.8, 1.25)))
    z_row = H - (np.arange(rows) + 0.5) / ppm  # height of each atlas row
    for fi, f in enumerate(world.faces):
        w = widths[fi]
        o = int(offsets[fi])
        if f.kind == "wall":
            mat, colour, scale = looks.get(f.region, ("painted", (170.0, 170.0, 170.0), 1.0))
            reg = world.regions.get(f.region)
            if reg is not None and reg.kind == "corridor" and rng.random() < 0.5:
                # long corridors: wall sections vary, so places along them differ
                mat = str(rng.choice(["painted", "plaster", "panel", "painted"]))
                colour = _pastel(rng)
            patch = _material(mat, rows, w, ppm, rng, colour, scale)
            skirting = z_row < 0.08
            patch[skirting] = np.array(colour, np.float32) * 0.45
        else:
            kind = world.box_kinds[f.box]
            hb = f.height
            patch = np.zeros((rows, w, 3), np.float32)
            r0 = int(np.floor((H - hb) * ppm))
            bh = rows - r0
            if kind == "shelf" and rng.random() < 0.85:
                sub = _books(bh, w, ppm, rng)
            elif kind == "pillar":
                sub = _material("plaster", bh, w, ppm, rng, (175, 175, 170), 1.0)
            else:
                sub = _cabinet(bh, w, ppm, rng, _pastel(rng, (0.1, 0.5), (0.35, 0.8)))
            patch[r0:] = sub
        # soft shading near floor and ceiling
        patch *= (0.8 + 0.2 * np.clip(z_row / 0.5, 0, 1) * np.clip((H - z_row) / 0.4, 0, 1))[
            :, None, None
        ]
        atlas[:, o : o + w] = patch
    for p in world.posters:
        f = world.faces[p.face]
        o = int(offsets[p.face])
        c0, c1 = o + int(p.s0 * ppm), o + int((p.s0 + p.width) * ppm)
        r0, r1 = int((H - p.z0 - p.height) * ppm), int((H - p.z0) * ppm)
        atlas[r0:r1, c0:c1] = _poster(p.image, r1 - r0, c1 - c0, rng)
    # orientation shading: faces facing +-x slightly darker than +-y (one light direction)
    shade = np.ones(atlas.shape[1], np.float32)
    for fi, f in enumerate(world.faces):
        o = int(offsets[fi])
        shade[o : o + widths[fi]] = (
            (0.86 if f.normal > 0 else 0.94) if f.axis == 0 else (1.0 if f.normal > 0 else 0.9)
        )
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
    top_tile = (
        0.75 + 0.25 * (top_tile - top_tile.mean()) / max(float(top_tile.std()), 1e-3) * 0.5
    ).astype(np.float32)
    top_color = np.array(
        [_pastel(rng, (0.2, 0.5), (0.4, 0.8)) for _ in range(len(world.boxes))], np.float32
    ).reshape(-1, 3)
    return BakedTextures(
        ppm,
        mips,
        offsets,
        floor,
        fppm,
        ceiling,
        cppm,
        np.repeat(top_tile, 3, axis=2),
        top_ppm,
        top_color,
    )


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
        if kind == "carpet":
            p = tint(
                tile(load_image("gravel.png"), h, w, 512 / (1.5 * fppm), rng.uniform(0, 512)),
                _pastel(rng, (0.15, 0.5), (0.3, 0.6)),
                0.7,
            )
        elif kind == "wood":
            grain = tile(load_image("gravel.png"), h, w, 0.6, rng.uniform(0, 512))
            p = tint(
                _blur(grain, (0, 0), sigmaX=5, sigmaY=0.5),
                _pastel(rng, (0.35, 0.55), (0.45, 0.7)),
                0.8,
            )
            plank = int(0.18 * fppm)
            p[(np.arange(h) % plank) == 0] *= 0.6
        else:
            base = np.array(_pastel(rng, (0.0, 0.15), (0.6, 0.85)), np.float32)
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


def face_s_sign(f: Face) -> bool:
    from litevloc.sim.world import _s_increasing

    return _s_increasing(f)
