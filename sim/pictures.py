"""Generated pictures for the walls of a varied building (all drawn here with OpenCV; no
image files, so no licence beyond this repository's own; the letters are OpenCV's built-in
Hershey fonts).

Every picture is a function of its kind, its design number and its text: the same three give
the same picture, so a building repeats a picture only where `decor` hands out a design twice.
Pictures are drawn at `SUPERSAMPLE` times the atlas resolution and shrunk with area averaging.

Kinds:

* `poster`: a coloured background, geometric shapes, a title of two or three words and
  lines of small print;
* `print`: a framed picture in a mat: an abstract composition, a landscape or a grid of
  coloured fields;
* `notice`: a cork board with pinned sheets of text;
* `plate`: a room-number plate (number large, name small);
* `sign`: a corridor direction sign (text and an arrow).

Pictures are drawn on uint8 canvases (OpenCV's text needs them); `picture` returns float32
(h, w, 3) RGB in 0..255.
"""

from __future__ import annotations

import colorsys
import zlib

import cv2
import numpy as np
from numpy.typing import NDArray

SUPERSAMPLE = 3
WORDS = (
    "open", "day", "science", "week", "coffee", "club", "safety", "first", "team", "meeting", "robot", "lab",
    "summer", "party", "health", "talk", "seminar", "music", "night", "yoga", "lunch", "break", "print",
    "recycle", "energy", "future", "vision", "map", "garden", "art", "show", "climate", "ideas", "book",
    "fair", "sport", "run", "north", "river", "light", "sound", "data", "design", "maker", "space", "ocean",
    "forest", "city", "bike", "train", "study", "group", "quiz", "film", "games", "welcome", "hello", "new",
    "spring", "autumn", "winter", "market", "craft", "code", "chess", "choir", "dance", "poster", "exhibit",
    "campus", "notice", "staff", "visitor", "help", "desk", "quiet", "zone", "fire", "exit", "drill", "water",
)
FONTS = (cv2.FONT_HERSHEY_SIMPLEX, cv2.FONT_HERSHEY_DUPLEX, cv2.FONT_HERSHEY_COMPLEX, cv2.FONT_HERSHEY_TRIPLEX,
         cv2.FONT_HERSHEY_PLAIN)


def _colour(rng: np.random.Generator, sat: tuple[float, float] = (0.3, 0.9),
            val: tuple[float, float] = (0.3, 0.95)) -> tuple[float, float, float]:
    r, g, b = colorsys.hsv_to_rgb(rng.random(), rng.uniform(*sat), rng.uniform(*val))
    return (r * 255, g * 255, b * 255)


def _words(rng: np.random.Generator, n: int) -> str:
    return " ".join(str(w) for w in rng.choice(WORDS, n))


def _text(img: NDArray[np.uint8], text: str, x: int, y: int, height: int, colour: tuple[float, float, float],
          font: int, max_w: int) -> int:
    """Draw `text` with its baseline at y, letters about `height` px tall, shrunk to fit
    `max_w` px; returns the drawn width (px)."""
    scale = height / 22.0
    (tw, _th), _ = cv2.getTextSize(text, font, scale, 1)
    if tw > max_w > 0:
        scale *= max_w / tw
    thick = max(1, round(scale * 1.6))
    cv2.putText(img, text, (x, y), font, scale, colour, thick, cv2.LINE_AA)
    return int(cv2.getTextSize(text, font, scale, thick)[0][0])


def _shapes(img: NDArray[np.uint8], rng: np.random.Generator, n: int, palette: list[tuple[float, float, float]],
            y0: int = 0) -> None:
    h, w = img.shape[:2]
    for _ in range(n):
        col = palette[int(rng.integers(len(palette)))]
        kind = int(rng.integers(5))
        cx, cy = int(rng.uniform(0, w)), int(rng.uniform(y0, h))
        r = int(rng.uniform(0.06, 0.3) * min(h, w)) + 1
        if kind == 0:
            cv2.circle(img, (cx, cy), r, col, -1, cv2.LINE_AA)
        elif kind == 1:
            cv2.rectangle(img, (cx - r, cy - r // 2), (cx + r, cy + r), col, -1)
        elif kind == 2:
            pts = (np.array([cx, cy]) + rng.uniform(-r, r, (3, 2))).astype(np.int32)
            cv2.fillPoly(img, [pts], col, cv2.LINE_AA)
        elif kind == 3:
            cv2.circle(img, (cx, cy), r, col, max(2, r // 4), cv2.LINE_AA)
        else:
            ang = rng.uniform(0, np.pi)
            d = (np.array([np.cos(ang), np.sin(ang)]) * 2 * r).astype(int)
            cv2.line(img, (cx - d[0], cy - d[1]), (cx + d[0], cy + d[1]), col, max(2, r // 5), cv2.LINE_AA)


def _poster(rng: np.random.Generator, h: int, w: int, text: tuple[str, ...]) -> NDArray[np.uint8]:
    palette = [_colour(rng) for _ in range(4)]
    top, bottom = np.array(_colour(rng, (0.1, 0.7), (0.5, 1.0))), np.array(_colour(rng, (0.1, 0.7), (0.3, 0.9)))
    t = np.linspace(0, 1, h)[:, None]
    img = np.ascontiguousarray(np.broadcast_to((top * (1 - t) + bottom * t)[:, None, :], (h, w, 3)).astype(np.uint8))
    _shapes(img, rng, int(rng.integers(4, 10)), palette, y0=int(0.25 * h))
    font = FONTS[int(rng.integers(len(FONTS) - 1))]
    ink = (20.0, 20.0, 25.0) if float(top.mean()) > 120 else (245.0, 245.0, 240.0)
    title = text[0] if text else _words(rng, int(rng.integers(2, 4))).upper()
    _text(img, title, int(0.06 * w), int(0.2 * h), int(0.12 * h), ink, font, int(0.88 * w))
    band = int(0.74 * h)
    cv2.rectangle(img, (0, band), (w, h), tuple(float(v) for v in top), -1)
    for k in range(int(rng.integers(2, 5))):
        y = band + int((k + 1) * 0.055 * h)
        if y < h - 2:
            _text(img, _words(rng, int(rng.integers(3, 6))), int(0.06 * w), y, int(0.035 * h), ink, font,
                  int(0.88 * w))
    return img


def _print(rng: np.random.Generator, h: int, w: int) -> NDArray[np.uint8]:
    img = np.empty((h, w, 3), np.uint8)
    style = int(rng.integers(3))
    if style == 0:  # abstract: overlapping translucent shapes on a light ground
        img[:] = _colour(rng, (0.0, 0.2), (0.8, 1.0))
        for _ in range(int(rng.integers(6, 14))):
            layer = img.copy()
            _shapes(layer, rng, 1, [_colour(rng)])
            a = rng.uniform(0.4, 0.9)
            img = (img * (1 - a) + layer * a).astype(np.uint8)
    elif style == 1:  # landscape: sky, ridges, sun
        sky0, sky1 = np.array(_colour(rng, (0.2, 0.6), (0.7, 1.0))), np.array(_colour(rng, (0.0, 0.4), (0.8, 1.0)))
        t = np.linspace(0, 1, h)[:, None]
        img[:] = (sky0 * (1 - t) + sky1 * t)[:, None, :].astype(np.uint8)
        cv2.circle(img, (int(rng.uniform(0.1, 0.9) * w), int(rng.uniform(0.1, 0.35) * h)), int(0.08 * min(h, w)) + 1,
                   _colour(rng, (0.5, 1.0), (0.9, 1.0)), -1, cv2.LINE_AA)
        for k in range(int(rng.integers(2, 5))):
            base = h * (0.45 + 0.15 * k)
            xs = np.linspace(0, w, 9)
            ys = base - rng.uniform(0, 0.25, 9) * h
            pts = np.concatenate([np.stack([xs, ys], 1), [[w, h], [0, h]]]).astype(np.int32)
            cv2.fillPoly(img, [pts], _colour(rng, (0.2, 0.8), (0.2, 0.8 - 0.1 * k)), cv2.LINE_AA)
    else:  # fields: a grid of coloured rectangles with dark lines
        img[:] = _colour(rng, (0.0, 0.35), (0.75, 1.0))
        xs = np.sort(np.concatenate([[0, w], rng.uniform(0, w, int(rng.integers(2, 5)))])).astype(int)
        ys = np.sort(np.concatenate([[0, h], rng.uniform(0, h, int(rng.integers(2, 5)))])).astype(int)
        for i in range(len(ys) - 1):
            for j in range(len(xs) - 1):
                if rng.random() < 0.45:
                    img[ys[i] : ys[i + 1], xs[j] : xs[j + 1]] = _colour(rng, (0.6, 1.0), (0.6, 1.0))
        lw = max(2, int(rng.uniform(0.008, 0.025) * min(h, w)))
        line = _colour(rng, (0.0, 0.8), (0.0, 0.3))
        for x in xs:
            img[:, max(x - lw, 0) : x + lw] = line
        for y in ys:
            img[max(y - lw, 0) : y + lw] = line
    return _frame(img, rng)


def _frame(img: NDArray[np.uint8], rng: np.random.Generator) -> NDArray[np.uint8]:
    """A mat and a frame around a picture (in place of its outer margin)."""
    h, w = img.shape[:2]
    f = max(3, int(0.05 * min(h, w)))
    m = max(3, int(rng.uniform(0.04, 0.1) * min(h, w)))
    out = img.copy()
    out[: f + m], out[-(f + m) :], out[:, : f + m], out[:, -(f + m) :] = 240, 240, 240, 240
    out[f + m : h - f - m, f + m : w - f - m] = cv2.resize(img, (w - 2 * (f + m), h - 2 * (f + m)),
                                                           interpolation=cv2.INTER_AREA)
    frame = np.array(_colour(rng, (0.0, 0.6), (0.05, 0.6)), np.uint8)
    out[:f], out[-f:], out[:, :f], out[:, -f:] = frame, frame, frame, frame
    return out


def _notice(rng: np.random.Generator, h: int, w: int) -> NDArray[np.uint8]:
    """A cork board with pinned sheets of text."""
    grain = np.random.default_rng(int(rng.integers(2**31)))  # size-dependent draws: their own stream
    cork = np.array([176, 132, 88], np.float32) + cv2.GaussianBlur(
        grain.normal(0, 18, (h, w)).astype(np.float32), (0, 0), 1.2)[..., None]
    img = np.ascontiguousarray(np.clip(cork, 0, 255).astype(np.uint8))
    frame = max(3, int(0.03 * min(h, w)))
    for _ in range(int(rng.integers(4, 10))):
        sw, sh = int(rng.uniform(0.16, 0.32) * w), int(rng.uniform(0.25, 0.5) * h)
        x0, y0 = int(rng.uniform(frame, w - sw - frame)), int(rng.uniform(frame, h - sh - frame))
        sheet = np.empty((sh, sw, 3), np.uint8)
        sheet[:] = _colour(rng, (0.0, 0.25), (0.85, 1.0))
        ink = (25.0, 25.0, 30.0) if rng.random() < 0.7 else _colour(rng, (0.6, 1.0), (0.3, 0.6))
        font = FONTS[int(rng.integers(len(FONTS)))]
        _text(sheet, _words(rng, 2).upper(), int(0.08 * sw), int(0.18 * sh), int(0.12 * sh), ink, font,
              int(0.84 * sw))
        for k in range(int(rng.integers(3, 8))):
            y = int((0.3 + 0.1 * k) * sh)
            if y < sh - 2:
                _text(sheet, _words(rng, int(rng.integers(2, 5))), int(0.08 * sw), y, int(0.05 * sh), ink, font,
                      int(0.84 * sw))
        img[y0 : y0 + sh, x0 : x0 + sw] = sheet
        cv2.circle(img, (x0 + sw // 2, y0 + max(3, sh // 14)), max(2, int(0.012 * w)), _colour(rng, (0.7, 1), (0.6, 1)),
                   -1, cv2.LINE_AA)
    img[:frame], img[-frame:], img[:, :frame], img[:, -frame:] = 95, 95, 95, 95
    return img


def _plate(rng: np.random.Generator, h: int, w: int, text: tuple[str, ...]) -> NDArray[np.uint8]:
    number, _, name = (text[0] if text else "").partition(" ")
    dark = rng.random() < 0.5
    img = np.empty((h, w, 3), np.uint8)
    img[:] = (45, 50, 60) if dark else (225, 225, 220)
    ink = (240.0, 240.0, 235.0) if dark else (25.0, 25.0, 30.0)
    _text(img, number, int(0.1 * w), int(0.55 * h), int(0.42 * h), ink, cv2.FONT_HERSHEY_DUPLEX, int(0.8 * w))
    if name:
        _text(img, name, int(0.1 * w), int(0.85 * h), int(0.18 * h), ink, cv2.FONT_HERSHEY_SIMPLEX, int(0.8 * w))
    b = max(2, int(0.04 * h))
    img[:b], img[-b:], img[:, :b], img[:, -b:] = 120, 120, 125, 125
    return img


def _sign(rng: np.random.Generator, h: int, w: int, text: tuple[str, ...]) -> NDArray[np.uint8]:
    img = np.empty((h, w, 3), np.uint8)
    img[:] = (20, 120, 60) if rng.random() < 0.5 else (25, 70, 150)
    _text(img, text[0] if text else _words(rng, 2), int(0.05 * w), int(0.68 * h), int(0.45 * h),
          (250.0, 250.0, 250.0), cv2.FONT_HERSHEY_SIMPLEX, int(0.9 * w))
    return img


def picture(kind: str, design: int, text: tuple[str, ...], h: int, w: int) -> NDArray[np.float32]:
    """The picture of (kind, design, text) at h x w atlas pixels (float32 RGB 0..255)."""
    if h < 2 or w < 2:
        return np.zeros((max(h, 0), max(w, 0), 3), np.float32)
    rng = np.random.default_rng([design, *(zlib.crc32(t.encode()) for t in (kind, *text))])
    H, W = h * SUPERSAMPLE, w * SUPERSAMPLE
    if kind == "poster":
        big = _poster(rng, H, W, text)
    elif kind == "print":
        big = _print(rng, H, W)
    elif kind == "notice":
        big = _notice(rng, H, W)
    elif kind == "plate":
        big = _plate(rng, H, W, text)
    elif kind == "sign":
        big = _sign(rng, H, W, text)
    else:
        raise ValueError(f"unknown picture kind {kind!r}")
    return np.asarray(cv2.resize(big, (w, h), interpolation=cv2.INTER_AREA), np.float32)
