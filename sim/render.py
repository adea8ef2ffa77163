"""CPU renderer of colour + metric depth for box worlds (vectorised numpy ray caster).

Every wall is vertical and every box axis-aligned, so a camera whose optical axis is
level (no pitch, no roll) sees each image column as one vertical plane through the
camera centre: one 2D ray cast per column over the floor plan gives the wall hit and
the boxes in front of it, and each pixel of the column then only compares its ray's
slope with those few hits and the floor/ceiling planes. A camera with pitch/roll is
rendered by rendering the level ("virtual") camera at the same centre over a slightly
larger field of view and warping it with the rotation homography (exact for colour up
to resampling; the range along each ray is rotation-invariant and is converted back to
z-depth).

Output: colour HxWx3 uint8 RGB (ideal: no noise; see `realism`) and depth HxW float32
metres (z along the optical axis), NaN where nothing was hit.
"""

from __future__ import annotations

import weakref
from functools import lru_cache

import cv2
import numpy as np
from numpy.typing import NDArray

from litevloc.base.errors import LiteVLocError
from litevloc.base.geometry import PinholeIntrinsics, check_rigid
from litevloc.sim.elements import s_increasing
from litevloc.sim.textures import MIP_LEVELS, BakedTextures, bake
from litevloc.sim.world import World

KIND_VOID, KIND_WALL, KIND_FLOOR, KIND_CEIL, KIND_SIDE, KIND_TOP = 0, 1, 2, 3, 4, 5


class RenderError(LiteVLocError, ValueError):
    """The camera pose cannot be rendered (e.g. looking straight up or down)."""


_BAKED: weakref.WeakKeyDictionary[World, BakedTextures] = weakref.WeakKeyDictionary()


def baked_textures(world: World) -> BakedTextures:
    """Textures of `world`, baked once per World object (kept while the world lives)."""
    tex = _BAKED.get(world)
    if tex is None:
        tex = bake(world)
        _BAKED[world] = tex
    return tex


@lru_cache(maxsize=8)
def _pixel_rays(
    fx: float, fy: float, cx: float, cy: float, w: int, h: int
) -> tuple[NDArray[np.float64], NDArray[np.float32]]:
    """(H, W, 3) rays (x/z, y/z, 1) of every pixel and their (H, W) lengths."""
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    d = np.stack([(u - cx) / fx, (v - cy) / fy, np.ones_like(u)], axis=-1)
    n = np.linalg.norm(d, axis=-1).astype(np.float32)
    d.setflags(write=False)
    n.setflags(write=False)
    return d, n


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


class Renderer:
    """Render RGB-D images of a `World` (see module docstring).

    Args:
        world: the world.
        max_range: rays are cast this far (m); farther boxes are ignored.
        light_falloff: brightness loss at 10 m range (0 = none), a mild exposure cue.
    """

    def __init__(self, world: World, max_range: float = 40.0, light_falloff: float = 0.25) -> None:
        self.world = world
        self.tex = baked_textures(world)
        self.max_range = float(max_range)
        self.light_falloff = float(light_falloff)
        faces = world.faces
        self._axis = np.array([f.axis for f in faces], np.int8)
        self._c = np.array([f.c for f in faces])
        self._lo = np.array([f.lo for f in faces])
        self._hi = np.array([f.hi for f in faces])
        self._normal = np.array([f.normal for f in faces], np.float64)
        self._sinc = np.array([s_increasing(f) for f in faces])
        self._wall = np.array([f.kind == "wall" for f in faces])
        box_face0 = [i for i, f in enumerate(faces) if f.kind == "box"]
        self._box_face0 = box_face0[0] if box_face0 else 0
        self._wall_idx = {a: np.nonzero(self._wall & (self._axis == a))[0] for a in (0, 1)}
        fppm = self.tex.floor_ppm
        self._floor_mips = [self.tex.floor]
        for _ in range(2):
            self._floor_mips.append(np.asarray(cv2.pyrDown(self._floor_mips[-1]), dtype=np.uint8))
        self._fppm = fppm

    # ------------------------------------------------------------------ public
    def render(
        self, T_world_camera: NDArray[np.floating], intrinsics: PinholeIntrinsics
    ) -> tuple[NDArray[np.uint8], NDArray[np.float32]]:
        """Colour (HxWx3 uint8 RGB) and z-depth (HxW float32 m, NaN = no hit) at a camera pose.

        Args:
            T_world_camera: 4x4 pose of the camera optical frame (x right, y down, z forward)
                in the world frame (z up).
            intrinsics: pinhole intrinsics of the output image.
        """
        col, depth = self._render(T_world_camera, intrinsics, want_color=True)
        assert col is not None
        return col, depth

    def _render(
        self, T_world_camera: NDArray[np.floating], intrinsics: PinholeIntrinsics, want_color: bool
    ) -> tuple[NDArray[np.uint8] | None, NDArray[np.float32]]:
        T = check_rigid(T_world_camera, "T_world_camera")
        K = intrinsics
        R_wc, p = T[:3, :3], T[:3, 3]
        fwd = R_wc[:, 2]
        horiz = np.hypot(fwd[0], fwd[1])
        if horiz < 0.35:
            raise RenderError("camera optical axis is within 20 degrees of vertical; not supported")
        f2 = fwd[:2] / horiz
        R_wv = np.array([[f2[1], 0.0, f2[0]], [-f2[0], 0.0, f2[1]], [0.0, -1.0, 0.0]])
        R_vc = R_wv.T @ R_wc
        rays, ray_len = _pixel_rays(K.fx, K.fy, K.cx, K.cy, K.width, K.height)
        level = np.allclose(R_vc, np.eye(3), atol=1e-9)
        if level:
            xn = np.asarray((np.arange(K.width) - K.cx) / K.fx, dtype=np.float64)
            yn = np.asarray((np.arange(K.height) - K.cy) / K.fy, dtype=np.float64)
            col, rng_ = self._render_level(p, R_wv, xn, yn, K.fx, want_color)
            depth = rng_ / ray_len
            return col, depth.astype(np.float32)
        dv = rays @ R_vc.T
        if np.any(dv[..., 2] <= 1e-3):
            raise RenderError("camera tilt too large for the level-camera warp")
        xv, yv = dv[..., 0] / dv[..., 2], dv[..., 1] / dv[..., 2]
        j0 = int(np.floor(K.fx * xv.min())) - 1
        j1 = int(np.ceil(K.fx * xv.max())) + 1
        i0 = int(np.floor(K.fy * yv.min())) - 1
        i1 = int(np.ceil(K.fy * yv.max())) + 1
        xn = np.arange(j0, j1 + 1) / K.fx
        yn = np.arange(i0, i1 + 1) / K.fy
        col_v, rng_v = self._render_level(p, R_wv, xn, yn, K.fx, want_color)
        map_x = (K.fx * xv - j0).astype(np.float32)
        map_y = (K.fy * yv - i0).astype(np.float32)
        rng_t = cv2.remap(rng_v, map_x, map_y, cv2.INTER_NEAREST, borderMode=cv2.BORDER_REPLICATE)
        depth = rng_t / ray_len
        if col_v is None:
            return None, depth.astype(np.float32)
        color = cv2.remap(col_v, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        return np.asarray(color, dtype=np.uint8), depth.astype(np.float32)

    def render_depth(
        self, T_world_camera: NDArray[np.floating], intrinsics: PinholeIntrinsics
    ) -> NDArray[np.float32]:
        """Z-depth only (HxW float32 m, NaN = no hit): the geometry of `render` without any
        texture sampling or shading, for consumers that read depth alone (the local planner).
        Bit-identical to the depth that `render` returns at the same pose."""
        return self._render(T_world_camera, intrinsics, want_color=False)[1]

    def render_stereo(
        self, T_world_camera: NDArray[np.floating], intrinsics: PinholeIntrinsics, baseline: float
    ) -> tuple[NDArray[np.uint8], NDArray[np.uint8], NDArray[np.float32]]:
        """Stereo pair (left colour, right colour, left depth); right = +x by `baseline`."""
        T = np.asarray(T_world_camera, dtype=np.float64)
        T_r = T.copy()
        T_r[:3, 3] = T[:3, 3] + T[:3, 0] * baseline
        left, depth = self.render(T, intrinsics)
        right, _ = self.render(T_r, intrinsics)
        return left, right, depth

    # --------------------------------------------------------------- internals
    def _walls(
        self, p: NDArray[np.float64], d: NDArray[np.float64]
    ) -> tuple[NDArray[np.float64], NDArray[np.intp], NDArray[np.float64]]:
        """Nearest wall per column ray: param t, face index, texture coordinate s (m)."""
        n = len(d)
        best_t = np.full(n, np.inf)
        best_f = np.full(n, -1, np.intp)
        best_s = np.zeros(n)
        for axis in (0, 1):
            idx = self._wall_idx[axis]
            if len(idx) == 0:
                continue
            other = 1 - axis
            da = d[:, axis : axis + 1]
            with np.errstate(divide="ignore", invalid="ignore"):
                t = (self._c[idx][None, :] - p[axis]) / da
            coord = p[other] + t * d[:, other : other + 1]
            ok = (
                (t > 1e-6)
                & (coord >= self._lo[idx])
                & (coord <= self._hi[idx])
                & (self._normal[idx] * da < 0)
            )
            t = np.where(ok, t, np.inf)
            k = np.argmin(t, axis=1)
            tk = t[np.arange(n), k]
            better = tk < best_t
            best_t = np.where(better, tk, best_t)
            fk = idx[k]
            ck = coord[np.arange(n), k]
            sk = np.where(self._sinc[fk], ck - self._lo[fk], self._hi[fk] - ck)
            best_f = np.where(better, fk, best_f)
            best_s = np.where(better, sk, best_s)
        return best_t, best_f, best_s

    def _boxes(self, p: NDArray[np.float64], d: NDArray[np.float64], t_wall: NDArray[np.float64]):
        """Boxes hit before the wall, nearest first: (K, n) t_in, t_out, height, face, s, box."""
        B = self.world.boxes
        if len(B) == 0:
            return None
        cx, cy = (B[:, 0] + B[:, 2]) / 2, (B[:, 1] + B[:, 3]) / 2
        near = np.nonzero(np.hypot(cx - p[0], cy - p[1]) < self.max_range)[0]
        if len(near) == 0:
            return None
        B = B[near]
        dx = np.where(np.abs(d[:, :1]) < 1e-12, 1e-12, d[:, :1])
        dy = np.where(np.abs(d[:, 1:2]) < 1e-12, 1e-12, d[:, 1:2])
        tx1, tx2 = (B[None, :, 0] - p[0]) / dx, (B[None, :, 2] - p[0]) / dx
        ty1, ty2 = (B[None, :, 1] - p[1]) / dy, (B[None, :, 3] - p[1]) / dy
        txn, txx = np.minimum(tx1, tx2), np.maximum(tx1, tx2)
        tyn, tyx = np.minimum(ty1, ty2), np.maximum(ty1, ty2)
        t_in, t_out = np.maximum(txn, tyn), np.minimum(txx, tyx)
        hit = (t_out > t_in) & (t_in > 1e-6) & (t_in < t_wall[:, None])
        counts = hit.sum(axis=1)
        K = int(counts.max())
        if K == 0:
            return None
        t_sort = np.where(hit, t_in, np.inf)
        order = np.argsort(t_sort, axis=1)[:, :K]
        rows = np.arange(len(d))[:, None]
        ti = t_sort[rows, order]
        valid = np.isfinite(ti)
        ti = np.where(valid, ti, 1e9)
        to = t_out[rows, order]
        via_x = (txn > tyn)[rows, order]
        bidx = near[order]
        dxs, dys = dx[:, 0][:, None], dy[:, 0][:, None]
        face_local = np.where(via_x, np.where(dxs > 0, 0, 1), np.where(dys > 0, 2, 3))
        face = self._box_face0 + 4 * bidx + face_local
        coord = np.where(via_x, p[1] + ti * dys, p[0] + ti * dxs)
        coord = np.where(valid, coord, 0.0)
        s = np.where(self._sinc[face], coord - self._lo[face], self._hi[face] - coord)
        h = self.world.boxes[bidx, 4]
        return ti.T, to.T, h.T, face.T, s.T, bidx.T, valid.T

    def _shade(
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
        H = self.world.wall_height
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

    def _render_level(
        self,
        p: NDArray[np.float64],
        R_wv: NDArray[np.float64],
        xn: NDArray[np.float64],
        yn: NDArray[np.float64],
        f: float,
        want_color: bool = True,
    ) -> tuple[NDArray[np.uint8] | None, NDArray[np.float32]]:
        """Render a level camera at p with columns xn and rows yn (normalised coordinates).

        Returns colour (len(yn), len(xn), 3) uint8 (None unless `want_color`) and range
        (m, float32, NaN = no hit).
        """
        H = self.world.wall_height
        h = float(p[2])
        if not (0.0 < h < H):
            raise RenderError(f"camera height {h:.2f} m is not between floor and ceiling (0, {H})")
        z_v, x_v = R_wv[:2, 2], R_wv[:2, 0]
        d = z_v[None, :] + xn[:, None] * x_v[None, :]  # (W, 2): point = p + t d, t = virtual z
        t_wall, f_wall, s_wall = self._walls(p, d)
        Y = yn[:, None]  # (H, 1)
        z_wall = h - Y * t_wall[None, :]
        with np.errstate(divide="ignore"):
            t_floor = np.where(Y > 0, h / Y, np.inf)
            t_ceil = np.where(Y < 0, (h - H) / Y, np.inf)
        hh, ww = len(yn), len(xn)
        kind = np.full((hh, ww), KIND_WALL, np.int8)
        t = np.broadcast_to(t_wall[None, :], (hh, ww)).copy()
        below, above = z_wall < 0, z_wall > H
        kind[below] = KIND_FLOOR
        kind[above] = KIND_CEIL
        tf = np.broadcast_to(t_floor, (hh, ww))
        tc = np.broadcast_to(t_ceil, (hh, ww))
        t[below] = tf[below]
        t[above] = tc[above]
        kind[~np.isfinite(t)] = KIND_VOID
        acol = (
            np.broadcast_to(
                (self.tex.face_offset[np.maximum(f_wall, 0)] + s_wall * self.tex.ppm)[None, :], (hh, ww)
            ).copy()
            if want_color
            else None
        )
        top_box = np.zeros((hh, ww), np.intp) if want_color else None
        boxes = self._boxes(p, d, t_wall)
        if boxes is not None:
            ti, to, hb, face, s, bidx, valid = boxes
            for k in range(len(ti) - 1, -1, -1):
                tik = ti[k][None, :]
                z_in = h - Y * tik
                side = valid[k][None, :] & (z_in >= 0) & (z_in <= hb[k][None, :]) & (tik < t)
                with np.errstate(divide="ignore"):
                    t_top = np.where(Y > 0, (h - hb[k][None, :]) / Y, np.inf)
                top = (
                    valid[k][None, :]
                    & (z_in > hb[k][None, :])
                    & (t_top <= to[k][None, :])
                    & (t_top < t)
                )
                t = np.where(side, np.broadcast_to(tik, t.shape), t)
                t = np.where(top, t_top, t)
                kind[side] = KIND_SIDE
                kind[top] = KIND_TOP
                if acol is None or top_box is None:
                    continue
                acol_k = np.broadcast_to(
                    (self.tex.face_offset[face[k]] + s[k] * self.tex.ppm)[None, :], acol.shape
                )
                acol[side] = acol_k[side]
                top_box[top] = np.broadcast_to(bidx[k][None, :], top_box.shape)[top]
        rng = t * np.sqrt(1.0 + xn[None, :] ** 2 + Y**2)
        if acol is None or top_box is None:
            return None, np.where(kind == KIND_VOID, np.nan, rng).astype(np.float32)
        color = self._shade(p, d, Y, f, kind, t, rng, acol, top_box)
        out_rng = np.where(kind == KIND_VOID, np.nan, rng).astype(np.float32)
        return np.clip(color, 0, 255).astype(np.uint8), out_rng
