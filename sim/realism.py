"""Seeded imaging effects: per-sequence lighting, image noise and blur, depth noise and holes.

The renderer produces ideal images; these functions degrade them the way a real RGB-D
camera does. Per-sequence `Lighting` is drawn once per recorded pass (so a query pass
is lit differently from the mapping pass); per-frame noise uses a generator seeded by
(sequence seed, frame index), so every frame is reproducible on its own.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from litevloc.base.params.sim import RealismParams


@dataclass(frozen=True)
class Lighting:
    """Lighting of one sequence: gain, gamma, per-channel cast (RGB gains), blur sigma."""

    brightness: float = 1.0
    gamma: float = 1.0
    cast: tuple[float, float, float] = (1.0, 1.0, 1.0)
    blur_sigma: float = 0.0


def sample_lighting(params: RealismParams, rng: np.random.Generator) -> Lighting:
    """Draw a sequence's lighting from the ranges in `params`."""
    cast = 1.0 + rng.uniform(-params.color_cast, params.color_cast, 3)
    return Lighting(
        float(rng.uniform(*params.brightness)),
        float(rng.uniform(*params.gamma)),
        (float(cast[0]), float(cast[1]), float(cast[2])),
        float(rng.uniform(*params.blur_sigma)),
    )


def apply_color(
    color: NDArray[np.uint8], lighting: Lighting, params: RealismParams, rng: np.random.Generator
) -> NDArray[np.uint8]:
    """HxWx3 uint8 RGB -> degraded HxWx3 uint8 RGB (lighting, blur, noise)."""
    if not params.enabled:
        return color
    lut = np.clip(255.0 * lighting.brightness * (np.arange(256) / 255.0) ** lighting.gamma, 0, 255)
    img = np.empty(color.shape, np.float32)
    for ch in range(3):
        img[..., ch] = (lut * lighting.cast[ch]).astype(np.float32)[color[..., ch]]
    if lighting.blur_sigma > 0.05:
        img = np.asarray(cv2.GaussianBlur(img, (0, 0), lighting.blur_sigma), dtype=np.float32)
    if params.noise_sigma > 0:
        img += rng.standard_normal((*img.shape[:2], 1), dtype=np.float32) * np.float32(
            params.noise_sigma * 0.6
        )
        img += rng.standard_normal(img.shape, dtype=np.float32) * np.float32(
            params.noise_sigma * 0.5
        )
    return np.clip(img + 0.5, 0, 255).astype(np.uint8)


def apply_depth(
    depth: NDArray[np.float32], params: RealismParams, rng: np.random.Generator
) -> NDArray[np.float32]:
    """HxW float32 metres -> noisy depth with NaN holes (range limits, edges, dropout)."""
    if not params.enabled:
        return depth
    d = depth.astype(np.float32, copy=True)
    finite = np.isfinite(d)
    z = np.where(finite, d, 0).astype(np.float32)
    d += (
        rng.standard_normal(d.shape, dtype=np.float32)
        * np.float32(params.depth_noise_per_m2)
        * z
        * z
    )
    # holes at depth discontinuities (stereo/ToF mixed pixels), slightly dilated
    gx = np.abs(np.diff(z, axis=1, prepend=z[:, :1]))
    gy = np.abs(np.diff(z, axis=0, prepend=z[:1, :]))
    edge = ((gx + gy) > 0.05 * np.maximum(z, 0.1)).astype(np.uint8)
    edge = cv2.dilate(edge, np.ones((3, 3), np.uint8)).astype(bool)
    holes = edge & (rng.random(d.shape, dtype=np.float32) < params.edge_hole_prob)
    holes |= rng.random(d.shape, dtype=np.float32) < params.dropout
    holes |= ~finite | (z < params.depth_min) | (z > params.depth_max)
    d[holes] = np.nan
    return d
