"""Surfaces: wall materials, furniture fronts and photographs, as float32 RGB patches.

The first simulator's surfaces (the "aliased" appearance, kept pixel for pixel) come from the
data folder that the scikit-image package ships (read with OpenCV by path; nothing is
downloaded). Only files whose licence the package documents as CC0 / public domain are used:

* materials: brick.png, gravel.png, grass.png (CC0Textures.com, CC0);
* pictures ("posters", `litevloc.sim.decor.POSTER_IMAGES`): astronaut.png, rocket.jpg,
  hubble_deep_field.jpg (NASA / SpaceX, public domain), camera.png (CC0, L. Varshney),
  chelsea.png (CC0, S. van der Walt), coffee.png (CC0, R. Michetti), coins.png (public
  domain), clock_motion.png (public domain, S. van der Walt), text.png (public domain),
  retina.jpg (CC0), cell.png (CC0).

The varied appearance generates each room's plaster and wallpaper from the room's own
random stream (`room_material`: no two rooms share a pattern) and gives clutter its own
surfaces (`clutter_front`); brick stays the one shared pattern (`repetitive_fraction` is
the hard axis of repeated walls).
"""

from __future__ import annotations

import colorsys
import importlib.util
from functools import lru_cache
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from litevloc.base.errors import LiteVLocError


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


def blur(
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


def pastel(
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


def material(
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
    # image, metres of wall its 512 pixels span, blur (texels), contrast
    tiled = {"brick": ("brick.png", 1.6, 0.0, 0.8), "plaster": ("gravel.png", 2.0, 2.5, 0.35),
             "wallpaper": ("grass.png", 1.2, 0.0, 0.8)}
    if kind in tiled:
        name, span_m, sigma, contrast = tiled[kind]
        p = tile(load_image(name), h, w, 512 / (span_m * scale * ppm), rng.uniform(0, 512), rng.uniform(0, 512))
        return tint(blur(p, (0, 0), sigma) if sigma else p, colour, contrast)
    if kind == "panel":
        grain = tile(load_image("gravel.png"), h, w, 0.5, rng.uniform(0, 512), rng.uniform(0, 512))
        wood = tint(blur(grain, (0, 0), sigmaX=0.5, sigmaY=6), (150, 105, 70), 0.8)
        plank = max(4, int(0.3 * ppm * scale))
        cols = np.arange(w) % plank
        wood[:, cols == 0] *= 0.55
        return wood
    raise ValueError(f"unknown material {kind!r}")


def books(h: int, w: int, ppm: float, rng: np.random.Generator) -> NDArray[np.float32]:
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


def cabinet(
    h: int, w: int, ppm: float, rng: np.random.Generator, colour: tuple[float, float, float]
) -> NDArray[np.float32]:
    grain = tile(load_image("gravel.png"), h, w, 0.4, rng.uniform(0, 512), rng.uniform(0, 512))
    out = tint(blur(grain, (0, 0), 2.0), colour, 0.4)
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


def photo_poster(name: str, h: int, w: int, rng: np.random.Generator) -> NDArray[np.float32]:
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




def room_material(kind: str, ppm: float, rng: np.random.Generator,
                  colour: tuple[float, float, float]) -> NDArray[np.float32] | None:
    """A room's wallpaper: one seamless tile of its own pattern (wallpaper is printed and
    repeats, in a real room too), drawn from the room's stream; None for the other materials."""
    return _wallpaper(ppm, rng, colour) if kind == "wallpaper" else None


def wall_surface(kind: str, h: int, w: int, ppm: float, style: np.random.Generator, rng: np.random.Generator,
                 colour: tuple[float, float, float]) -> NDArray[np.float32] | None:
    """One wall face's own brick, plaster or panelling (h x w atlas pixels): the room's style
    (`style`: the room's stream, drawn the same for each of its faces) and this face's own
    bricks, noise and grain (`rng`), so no stretch of wall repeats another. None for the other
    materials."""
    if kind == "brick":
        return _bricks(h, w, ppm, rng, colour)
    if kind == "plaster":
        sigma, amplitude = style.uniform(1.5, 5.0), style.uniform(6.0, 14.0)
        noise = blur(rng.normal(0, 1, (h, w)).astype(np.float32), (0, 0), sigma)
        noise = noise / max(float(noise.std()), 1e-6) * amplitude
        return np.clip(np.array(colour, np.float32)[None, None, :] + noise[..., None], 0, 255)
    if kind == "panel":
        r, g, b = colorsys.hsv_to_rgb(style.uniform(0.04, 0.11), style.uniform(0.35, 0.7), style.uniform(0.35, 0.75))
        plank = max(4, int(style.uniform(0.12, 0.35) * ppm))
        grain = blur(rng.normal(0, 1, (h, w)).astype(np.float32), (0, 0), sigmaX=0.5, sigmaY=8)
        wood = np.array([r, g, b], np.float32)[None, None, :] * 255 * (
            1 + 0.075 * grain[..., None] / max(float(grain.std()), 1e-6))
        shades = rng.uniform(0.88, 1.12, w // plank + 1)  # each plank its own shade
        wood *= np.repeat(shades, plank)[:w][None, :, None].astype(np.float32)
        wood[:, (np.arange(w) % plank) == 0] *= 0.55
        return np.asarray(np.clip(wood, 0, 255), np.float32)
    return None


def _bricks(h: int, w: int, ppm: float, rng: np.random.Generator,
            colour: tuple[float, float, float]) -> NDArray[np.float32]:
    """Running-bond brickwork (bricks ~0.215 x 0.065 m, 1 cm joints) over h x w atlas pixels,
    every brick its own shade: a regular pattern, but no stretch of wall like another. Drawn
    at 4x and shrunk (the joints are thinner than an atlas pixel)."""
    up = 4
    ys, xs = (np.arange(h * up) + 0.5) / (ppm * up), (np.arange(w * up) + 0.5) / (ppm * up)
    course = np.floor(ys / 0.075).astype(np.int64)
    shift = (course % 2) * 0.1125
    along = xs[None, :] + shift[:, None]
    brick = np.floor(along / 0.225).astype(np.int64)
    shade = rng.uniform(0.78, 1.15, (int(course.max()) + 1, int(brick.max()) + 1)).astype(np.float32)
    tint_ = rng.normal(0, 6, (int(course.max()) + 1, int(brick.max()) + 1, 3)).astype(np.float32)
    t = np.array(colour, np.float32)[None, None, :] * shade[course[:, None], brick][..., None] \
        + tint_[course[:, None], brick]
    joint = ((ys % 0.075) < 0.01)[:, None] | ((along % 0.225) < 0.01)
    t[joint] = np.array(colour, np.float32) * 0.35 + 150
    t += rng.normal(0, 5, t.shape[:2])[..., None].astype(np.float32)
    return np.asarray(cv2.resize(t, (w, h), interpolation=cv2.INTER_AREA), np.float32)


def floor_patch(kind: str, h: int, w: int, fppm: float, rng: np.random.Generator) -> NDArray[np.float32]:
    """A room's own floor (varied appearance): "carpet" (noise of its own grain and colour),
    "wood" (planks of their own shades) or "tiles" (its own tile size and colour)."""
    if kind == "carpet":
        grain = blur(rng.normal(0, 1, (h, w)).astype(np.float32), (0, 0), rng.uniform(0.8, 2.5))
        fleck = blur(rng.normal(0, 1, (h, w)).astype(np.float32), (0, 0), rng.uniform(4.0, 10.0))
        g = grain / max(float(grain.std()), 1e-6) * 10 + fleck / max(float(fleck.std()), 1e-6) * 8
        return np.clip(np.array(pastel(rng, (0.15, 0.6), (0.25, 0.6)), np.float32) + g[..., None], 0, 255)
    if kind == "wood":
        out = np.empty((h, w, 3), np.float32)
        base = np.array(pastel(rng, (0.35, 0.6), (0.4, 0.75)), np.float32)
        plank, length = max(3, int(rng.uniform(0.12, 0.22) * fppm)), max(8, int(rng.uniform(0.8, 1.6) * fppm))
        grain = blur(rng.normal(0, 1, (h, w)).astype(np.float32), (0, 0), sigmaX=6, sigmaY=0.5)
        for r0 in range(0, h, plank):
            off = int(rng.integers(length))
            for c0 in range(-off, w, length):
                out[r0 : r0 + plank, max(c0, 0) : c0 + length] = base * rng.uniform(0.8, 1.15)
        out += grain[..., None] / max(float(grain.std()), 1e-6) * 6
        out[(np.arange(h) % plank) == 0] *= 0.6
        return out
    size = max(4, int(rng.uniform(0.3, 0.6) * fppm))
    out = np.empty((h, w, 3), np.float32)
    out[:] = pastel(rng, (0.0, 0.2), (0.55, 0.85))
    shades = rng.uniform(0.93, 1.07, (h // size + 1, w // size + 1))
    out *= np.kron(shades, np.ones((size, size)))[:h, :w, None].astype(np.float32)
    out += rng.normal(0, 3, (h, w, 1)).astype(np.float32)
    out[(np.arange(h) % size) == 0] *= 0.7
    out[:, (np.arange(w) % size) == 0] *= 0.7
    return out


def _wallpaper(ppm: float, rng: np.random.Generator, colour: tuple[float, float, float]) -> NDArray[np.float32]:
    """One period of a wallpaper pattern (stripes, dots, diamonds or sprigs) in two colours."""
    p = max(8, int(rng.uniform(0.18, 0.5) * ppm)) * 3  # drawn 3x, shrunk at the end
    ground = np.array(colour, np.float32)
    r, g, b = colorsys.hsv_to_rgb(rng.random(), rng.uniform(0.2, 0.7), rng.uniform(0.25, 0.9))
    ink = (r * 255, g * 255, b * 255)
    t = np.empty((p, p, 3), np.float32)
    t[:] = ground
    style = int(rng.integers(4))
    if style == 0:
        edges = np.sort(rng.uniform(0, p, int(rng.integers(2, 5))).astype(int))
        for a, c in zip(edges[::2], edges[1::2], strict=False):
            t[:, a:c] = ink
    else:
        n_motifs = 1 if style < 3 else int(rng.integers(3, 7))
        for _ in range(n_motifs):
            cx, cy = (p // 2, p // 2) if style < 3 else (int(rng.uniform(0, p)), int(rng.uniform(0, p)))
            size = int(rng.uniform(0.12, 0.3) * p) + 1
            for dx in (-p, 0, p):  # drawn with its wrapped copies: the tile is seamless
                for dy in (-p, 0, p):
                    c = (cx + dx, cy + dy)
                    if style == 1:
                        cv2.circle(t, c, size, ink, -1, cv2.LINE_AA)
                    elif style == 2:
                        pts = np.array([[c[0], c[1] - size], [c[0] + size, c[1]], [c[0], c[1] + size],
                                        [c[0] - size, c[1]]], np.int32)
                        cv2.fillPoly(t, [pts], ink, cv2.LINE_AA)
                    else:
                        cv2.ellipse(t, c, (size, max(1, size // 3)), float(rng.uniform(0, 180)), 0, 360, ink, -1,
                                    cv2.LINE_AA)
    return np.asarray(cv2.resize(t, (p // 3, p // 3), interpolation=cv2.INTER_AREA), np.float32)


def clutter_front(kind: str, h: int, w: int, ppm: float, rng: np.random.Generator) -> NDArray[np.float32]:
    """The side of a clutter box (bin, plant, stool, crate), h x w atlas pixels."""
    out = np.empty((h, w, 3), np.float32)
    cols = np.arange(w)
    if kind == "bin":
        out[:] = pastel(rng, (0.3, 0.9), (0.15, 0.6))
        out[:, (cols % max(3, int(0.05 * ppm))) == 0] *= 0.7
        out[: max(2, int(0.03 * ppm))] *= 0.6
    elif kind == "plant":
        pot = int(0.45 * h)
        out[:] = (40, 80 + 60 * rng.random(), 35)
        for _ in range(int(0.03 * h * w / max(ppm, 1)) + 12):
            cv2.ellipse(out, (int(rng.uniform(0, w)), int(rng.uniform(0, h - pot))),
                        (max(1, int(0.06 * ppm)), max(1, int(0.025 * ppm))), float(rng.uniform(0, 180)), 0, 360,
                        pastel(rng, (0.5, 0.9), (0.3, 0.75)) if rng.random() < 0.2 else
                        (30 + 40 * rng.random(), 110 + 90 * rng.random(), 40), -1, cv2.LINE_AA)
        out[h - pot :] = pastel(rng, (0.5, 0.8), (0.45, 0.75))
        out[h - pot : h - pot + max(2, int(0.03 * ppm))] *= 0.75
    elif kind == "stool":
        out[:] = (35, 35, 38)
        wood = np.array(pastel(rng, (0.3, 0.6), (0.4, 0.75)), np.float32)
        out[: max(2, int(0.06 * ppm))] = wood
        leg = max(2, int(0.04 * ppm))
        out[:, :leg], out[:, w - leg :] = wood * 0.8, wood * 0.8
    else:  # crate: cardboard, tape, a printed label
        out[:] = (165 + 25 * rng.random(), 125 + 20 * rng.random(), 80)
        out += rng.normal(0, 4, (h, w, 1)).astype(np.float32)
        tape = max(2, int(0.05 * ppm))
        out[:tape] = (200, 175, 120)
        lh, lw = h // 3, w // 2
        if lh > 3 and lw > 3:
            y0, x0 = h // 3, w // 4
            out[y0 : y0 + lh, x0 : x0 + lw] = 235
            for k in range(3):
                yy = y0 + int((k + 0.5) * lh / 3)
                out[yy, x0 + 2 : x0 + int(lw * rng.uniform(0.4, 0.95))] = 40
    return out
