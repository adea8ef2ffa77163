"""The 2D ray cast of a level camera over a box world's floor plan (`render.Renderer`'s geometry).

Every wall is vertical and every box axis-aligned, so one ray per image column, cast in the
floor plane from the camera centre `p` along `d` (a point is p + t d), gives the nearest wall
and the boxes in front of it; `render` then sorts each pixel of the column among those hits.
Texture coordinates s are metres along a face, left to right as seen from its front.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from litevloc.sim.elements import s_increasing
from litevloc.sim.world import World

# what a pixel's ray hit first
KIND_VOID, KIND_WALL, KIND_FLOOR, KIND_CEIL, KIND_SIDE, KIND_TOP = 0, 1, 2, 3, 4, 5

# (K, n) per column ray, nearest box first: t_in, t_out, box height (m), face index, texture
# coordinate s (m), box index, whether the k-th hit exists
BoxHits = tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.intp],
                NDArray[np.float64], NDArray[np.intp], NDArray[np.bool_]]


class FloorPlanCaster:
    """Column rays against the walls and boxes of a `World`.

    Args:
        world: the world (its faces: walls, then four sides per box; its boxes (B, 5)
            x0, y0, x1, y1, height, read at each cast).
        max_range: boxes whose centre is farther than this (m) are ignored.
    """

    def __init__(self, world: World, max_range: float) -> None:
        self.world = world
        self.max_range = float(max_range)
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

    def walls(
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

    def boxes(self, p: NDArray[np.float64], d: NDArray[np.float64], t_wall: NDArray[np.float64]) -> BoxHits | None:
        """Boxes the (n, 2) column rays `d` hit before their wall (`t_wall`), nearest first
        (`BoxHits`); None when no ray hits a box."""
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
