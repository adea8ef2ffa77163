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

The column ray cast is `raycast.FloorPlanCaster`, the texturing and shading of the hits
`shading.Shader`; this module composes the hits of each pixel and models the camera.

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
from litevloc.sim.raycast import KIND_CEIL, KIND_FLOOR, KIND_SIDE, KIND_TOP, KIND_VOID, KIND_WALL, FloorPlanCaster
from litevloc.sim.shading import Shader
from litevloc.sim.textures import BakedTextures, bake
from litevloc.sim.world import World


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
        self._caster = FloorPlanCaster(world, self.max_range)
        self._shader = Shader(self.tex, world.wall_height, self.light_falloff)

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
        t_wall, f_wall, s_wall = self._caster.walls(p, d)
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
        boxes = self._caster.boxes(p, d, t_wall)
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
        color = self._shader.shade(p, d, Y, f, kind, t, rng, acol, top_box)
        out_rng = np.where(kind == KIND_VOID, np.nan, rng).astype(np.float32)
        return np.clip(color, 0, 255).astype(np.uint8), out_rng
