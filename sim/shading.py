"""Colour of the pixels of a level camera from what their rays hit (`render.Renderer`'s
appearance): the baked textures sampled at a mip level chosen by each pixel's footprint,
floor, ceiling and box tops from world-aligned maps, darker with distance.
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

from litevloc.sim.raycast import KIND_CEIL, KIND_FLOOR, KIND_SIDE, KIND_TOP, KIND_VOID, KIND_WALL
from litevloc.sim.textures import MIP_LEVELS, BakedTextures


def _sample(
    A: NDArray[np.uint8], r: NDArray[np.float64], c: NDArray[np.float64], bilinear: bool
) -> NDArray[np.float32]:
    """Texels of A (h, w, 3) at continuous (row, col) coordinates (texel centres at +0.5)."""
    h, w = A.shape[:2]
    if not bilinear:
        ri = np.clip(r.astype(np.intp), 0, h - 1)
        ci = np.clip(c.astype(np.intp), 0, w - 1)
        return A.reshape(-1, 3).take(ri * w + ci, axis=0).astype(np.float32)
    r = r - 0.5
    c = c - 0.5
    r0 = np.floor(r)
    c0 = np.floor(c)
    fr = (r - r0).astype(np.float32)[:, None]
    fc = (c - c0).astype(np.float32)[:, None]
    r0i = np.clip(r0.astype(np.intp), 0, h - 1)
    c0i = np.clip(c0.astype(np.intp), 0, w - 1)
    dr = np.where(r0i < h - 1, w, 0)
    dc = np.where(c0i < w - 1, 1, 0)
    flat = A.reshape(-1, 3)
    i00 = r0i * w + c0i
    top = flat.take(i00, axis=0) * (1 - fc) + flat.take(i00 + dc, axis=0) * fc
    bot = flat.take(i00 + dr, axis=0) * (1 - fc) + flat.take(i00 + dr + dc, axis=0) * fc
    return np.asarray(top * (1 - fr) + bot * fr, dtype=np.float32)


class Shader:
    """Shade hits with a world's baked textures.

    Args:
        tex: the world's baked textures.
        wall_height: floor to ceiling (m).
        light_falloff: brightness loss at 10 m range (0 = none), a mild exposure cue.
    """

    def __init__(self, tex: BakedTextures, wall_height: float, light_falloff: float) -> None:
        self.tex = tex
        self.wall_height = wall_height
        self.light_falloff = float(light_falloff)
        self._floor_mips = [self.tex.floor]
        for _ in range(2):
            self._floor_mips.append(np.asarray(cv2.pyrDown(self._floor_mips[-1]), dtype=np.uint8))
        self._fppm = self.tex.floor_ppm

    def shade(
        self,
        p: NDArray[np.float64],
        d: NDArray[np.float64],
        Y: NDArray[np.float64],
        f: float,
        kind: NDArray[np.int8],
        t: NDArray[np.float64],
        rng: NDArray[np.float64],
        acol: NDArray[np.float64],
        top_box: NDArray[np.intp],
    ) -> NDArray[np.float32]:
        """Colour (float, 0-255) of each pixel of a level camera at `p` from what it hit (`kind`,
        ray parameter `t`, range `rng` m; `d` (W, 2) column directions, `Y` (H, 1) normalised
        rows): textured walls and box sides (atlas column `acol`), floor, ceiling and box tops
        (`top_box`), grey where nothing was hit, darker with distance."""
        H = self.wall_height
        h = float(p[2])
        hh, ww = kind.shape
        color = np.zeros((hh, ww, 3), np.float32)
        # texture level per pixel from its footprint in texels; -1 = magnified: bilinear level 0
        lvl = np.clip(
            np.round(np.log2(np.maximum(rng * self.tex.ppm / f, 1e-6))), -1, MIP_LEVELS - 1
        ).astype(np.int8)
        # walls and box sides: atlas
        m = (kind == KIND_WALL) | (kind == KIND_SIDE)
        if m.any():
            zz = h - Y * t
            arow = (H - zz) * self.tex.ppm
            for L in range(-1, MIP_LEVELS):
                mm = m & (lvl == L)
                if not mm.any():
                    continue
                A = self.tex.atlas[max(L, 0)]
                sc = 0.5 ** max(L, 0)
                color[mm] = _sample(A, arow[mm] * sc, acol[mm] * sc, bilinear=L < 0)
        # floor and box tops: world-aligned maps
        mf = kind == KIND_FLOOR
        mt = kind == KIND_TOP
        mc = kind == KIND_CEIL
        if mf.any() or mt.any() or mc.any():
            wx = p[0] + t * d[None, :, 0]
            wy = p[1] + t * d[None, :, 1]
            if mf.any():
                flvl = np.clip(
                    np.round(np.log2(np.maximum(rng * self._fppm / f, 1e-6))), -1, 2
                ).astype(np.int8)
                for L in range(-1, 3):
                    mm = mf & (flvl == L)
                    if not mm.any():
                        continue
                    A = self._floor_mips[max(L, 0)]
                    sc = self._fppm * 0.5 ** max(L, 0)
                    color[mm] = _sample(A, wy[mm] * sc, wx[mm] * sc, bilinear=L < 0)
            if mc.any():
                A = self.tex.ceiling
                sc = self.tex.ceiling_ppm
                r_ = np.clip((wy[mc] * sc).astype(np.intp), 0, A.shape[0] - 1)
                c_ = np.clip((wx[mc] * sc).astype(np.intp), 0, A.shape[1] - 1)
                color[mc] = A[r_, c_]
            if mt.any():
                T_ = self.tex.top_tile
                n = T_.shape[0]
                r_ = (wy[mt] * self.tex.top_ppm).astype(np.intp) % n
                c_ = (wx[mt] * self.tex.top_ppm).astype(np.intp) % n
                color[mt] = T_[r_, c_] * self.tex.top_color[top_box[mt]]
        color[kind == KIND_VOID] = 128
        if self.light_falloff > 0:
            color *= (1.0 - self.light_falloff * np.clip(rng / 10.0, 0, 1))[..., None].astype(
                np.float32
            )
        return color
