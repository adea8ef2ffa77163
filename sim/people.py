"""People walking across the camera's view: moving occluders with depth, composited into a
rendered frame (colour and depth) at its time stamp.

Each person crosses the view again and again: a crossing starts every `period` seconds (drawn
per person), at a distance ahead of the camera and in a direction drawn per crossing, walking
sideways at the person's speed from `CROSS_HALF_WIDTH_M` on one side to the same on the other;
between crossings they are out of view. Positions are taken relative to the camera at each
frame (people that keep walking through whatever the robot looks at), and a person whose spot
is inside a wall or a piece of furniture is not drawn. A person is a vertical cylinder
(`RADIUS_M`, `HEIGHT_M`) in trousers, a shirt and a head. The robot's collisions and routes
ignore people; the depth images and the local planner see them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from litevloc.base.geometry import PinholeIntrinsics

RADIUS_M = 0.22
HEIGHT_M = 1.72
CROSS_HALF_WIDTH_M = 2.6
DISTANCE_M = (1.4, 4.0)  # ahead of the camera, per crossing


class _Space(Protocol):
    def is_free(self, xy: NDArray[np.floating], radius: float) -> bool: ...


@dataclass(frozen=True)
class Walkers:
    """`count` people drawn from `seed` (see module docstring)."""

    count: int
    seed: int

    def _person(self, k: int) -> tuple[float, float, float, NDArray[np.float32]]:
        """Person k's period (s), phase (s), speed (m/s) and colours (3, 3: trousers, shirt, skin)."""
        rng = np.random.default_rng([self.seed, 20, k])
        period = float(rng.uniform(6.0, 9.0))
        speed = float(rng.uniform(1.0, 1.4))
        colours = np.array([rng.uniform(30, 120, 3), rng.uniform(40, 230, 3),
                            rng.uniform([150, 110, 80], [230, 180, 150])], np.float32)
        return period, k * period / max(self.count, 1), speed, colours

    def at(self, t_s: float, T_world_camera: NDArray[np.floating],
           space: _Space) -> list[tuple[NDArray[np.float64], NDArray[np.float32]]]:
        """People in view at time `t_s`: (xy world m, colours) of each one drawn."""
        out = []
        fwd = np.asarray(T_world_camera[:2, 2], dtype=np.float64)
        fwd = fwd / max(float(np.linalg.norm(fwd)), 1e-9)
        left = np.array([-fwd[1], fwd[0]])
        p = np.asarray(T_world_camera[:2, 3], dtype=np.float64)
        for k in range(self.count):
            period, phase, speed, colours = self._person(k)
            e = int(np.floor((t_s + phase) / period))
            tau = t_s + phase - e * period
            rng = np.random.default_rng([self.seed, 21, k, e & 0x7FFFFFFF])
            dist = float(rng.uniform(*DISTANCE_M))
            direction = float(rng.choice([-1.0, 1.0]))
            lateral = direction * (-CROSS_HALF_WIDTH_M + speed * tau)
            if abs(lateral) > CROSS_HALF_WIDTH_M:
                continue
            xy = p + fwd * dist + left * lateral
            if space.is_free(xy, RADIUS_M):
                out.append((xy, colours))
        return out


def composite(people: list[tuple[NDArray[np.float64], NDArray[np.float32]]], T_world_camera: NDArray[np.floating],
              K: PinholeIntrinsics, color: NDArray[np.uint8] | None, depth: NDArray[np.float32]) -> int:
    """Draw `people` into an ideal frame in place (colour HxWx3 uint8, may be None; z-depth HxW
    float32 m, NaN = no hit) where a person is nearer than what was rendered; returns the
    number of pixels they cover."""
    if not people:
        return 0
    T = np.asarray(T_world_camera, dtype=np.float64)
    u, v = np.meshgrid(np.arange(K.width, dtype=np.float64), np.arange(K.height, dtype=np.float64))
    rays = np.stack([(u - K.cx) / K.fx, (v - K.cy) / K.fy, np.ones_like(u)], axis=-1) @ T[:3, :3].T
    o = T[:3, 3]
    dx, dy, dz = rays[..., 0], rays[..., 1], rays[..., 2]
    a = dx * dx + dy * dy
    covered = np.zeros(depth.shape, bool)
    for xy, colours in people:
        ox, oy = o[0] - xy[0], o[1] - xy[1]
        b = 2 * (dx * ox + dy * oy)
        disc = b * b - 4 * a * (ox * ox + oy * oy - RADIUS_M**2)
        with np.errstate(invalid="ignore", divide="ignore"):
            s = (-b - np.sqrt(disc)) / (2 * a)  # ray parameter of the front hit = z-depth (rays have z = 1)
        z = o[2] + s * dz
        hit = (disc > 0) & (s > 0.05) & (z >= 0) & (z <= HEIGHT_M) & ~(depth <= s)
        if not hit.any():
            continue
        depth[hit] = s[hit].astype(np.float32)
        covered |= hit
        if color is None:
            continue
        part = np.where(z < 0.85, 0, np.where(z < 1.48, 1, 2))
        nx, ny = ox + s * dx, oy + s * dy  # hit point relative to the axis: the surface normal x radius
        facing = np.clip(-(nx * dx + ny * dy) / (RADIUS_M * np.sqrt(np.maximum(a, 1e-12))), 0, 1)
        shade = (0.55 + 0.45 * facing)[..., None]
        color[hit] = np.clip(colours[part[hit]] * shade[hit], 0, 255).astype(np.uint8)
    return int(covered.sum())
