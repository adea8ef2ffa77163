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


@dataclass(frozen=True)
class RealismParams:
    """Ranges of the imaging effects (all seeded). `enabled: false` gives ideal images."""

    enabled: bool = True
    brightness: tuple[float, float] = (0.75, 1.2)  # per-sequence gain
    gamma: tuple[float, float] = (0.85, 1.2)  # per-sequence gamma
    color_cast: float = 0.08  # max relative per-channel gain deviation
    blur_sigma: tuple[float, float] = (0.0, 0.7)  # per-sequence Gaussian blur (pixels)
    noise_sigma: float = 2.5  # per-pixel Gaussian noise (grey levels)
    depth_noise_per_m2: float = 0.002  # depth sigma = k * z^2 metres
    depth_min: float = 0.2  # closer is invalid (NaN)
    depth_max: float = 10.0  # farther is invalid (NaN)
    edge_hole_prob: float = 0.6  # chance that a pixel at a depth edge is a hole
    dropout: float = 0.005  # random invalid depth pixels

    def __post_init__(self) -> None:
        for name in ("brightness", "gamma", "blur_sigma"):
            lo, hi = getattr(self, name)
            if not (0 <= lo <= hi) or not np.isfinite(hi):
                raise ValueError(f"{name} must be [lo, hi] with 0 <= lo <= hi, got {(lo, hi)}")
        if self.brightness[0] <= 0 or self.gamma[0] <= 0:
            raise ValueError("brightness and gamma must be > 0")
        for name in (
            "color_cast",
            "noise_sigma",
            "depth_noise_per_m2",
            "edge_hole_prob",
            "dropout",
        ):
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise ValueError(f"{name} must be >= 0, got {v}")
        if self.edge_hole_prob > 1 or self.dropout > 1:
            raise ValueError("edge_hole_prob and dropout are probabilities in [0, 1]")
        if not (0 <= self.depth_min < self.depth_max):
            raise ValueError(
                f"need 0 <= depth_min < depth_max, got {self.depth_min}, {self.depth_max}"
            )


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
