"""A camera over a textured floor, rendered exactly: two views of a corridor's floor seen at a
grazing angle, their depth, and pixels on it (tests of keypoint alignment and the edges using it)."""

from __future__ import annotations

import cv2
import numpy as np

K = np.array([[320.0, 0, 320], [0, 320.0, 240], [0, 0, 1]])
W, H = 640, 480


def texture(seed: int = 0, size: int = 1024) -> np.ndarray:
    """Smooth random blobs: a floor-like texture, texels 1 cm."""
    rng = np.random.default_rng(seed)
    t = cv2.GaussianBlur(rng.uniform(0, 255, (size, size)).astype(np.float32), (0, 0), 3.0)
    t = (t - t.min()) / (t.max() - t.min()) * 255
    return t.astype(np.float32)


def floor_camera(T_world_camera: np.ndarray, tex: np.ndarray,
                 texel_m: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
    """Colour (HxWx3 uint8) and depth (HxW metres) of a camera over a textured floor z = 0
    (world), texture pixel (i, j) at world (x, y) = (j, i) * texel_m - half the texture."""
    T_cw = np.linalg.inv(T_world_camera)
    half = tex.shape[0] * texel_m / 2
    # texture pixel -> world point on the floor -> camera -> image
    A = np.array([[texel_m, 0, -half], [0, texel_m, -half], [0, 0, 0], [0, 0, 1]])
    Hm = K @ (T_cw[:3] @ A)
    img = cv2.warpPerspective(tex, Hm, (W, H), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
    u, v = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
    rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], axis=-1)
    R, c = T_world_camera[:3, :3], T_world_camera[:3, 3]
    dz = rays @ R[2]  # world z per unit camera depth along each ray
    with np.errstate(divide="ignore", invalid="ignore"):
        depth = np.where(dz < -1e-6, -c[2] / dz, np.nan)
    depth[depth > 8.0] = np.nan
    gray = np.clip(img, 0, 255).astype(np.uint8)
    return np.repeat(gray[..., None], 3, axis=2), depth.astype(np.float32)


def looking_along_x(x: float, height: float = 0.5, pitch_deg: float = 10.0) -> np.ndarray:
    """T_world_camera of a camera at (x, 0, height) looking along +x, pitched down."""
    p = np.radians(pitch_deg)
    fwd = np.array([np.cos(p), 0, -np.sin(p)])
    right = np.array([0, -1.0, 0])
    down = np.cross(fwd, right)  # camera x right, y down the image, z forward
    T = np.eye(4)
    T[:3, :3] = np.column_stack([right, down, fwd])
    T[:3, 3] = [x, 0, height]
    return T


def floor_pair() -> dict[str, np.ndarray]:
    """A source camera 0.3 m ahead of the target along a corridor's floor (grazing view)."""
    tex = texture()
    T_ws, T_wt = looking_along_x(-2.7), looking_along_x(-3.0)
    cs, ds = floor_camera(T_ws, tex)
    ct, dt = floor_camera(T_wt, tex)
    return {"cs": cs, "ds": ds, "ct": ct, "dt": dt, "T_t_s": np.linalg.inv(T_wt) @ T_ws}


def keypoints(depth: np.ndarray, n: int, seed: int) -> np.ndarray:
    """Source pixels on the floor 1-4 m away, away from the borders."""
    rng = np.random.default_rng(seed)
    uv = np.column_stack([rng.uniform(40, W - 40, 4 * n), rng.uniform(300, H - 40, 4 * n)])
    z = depth[np.rint(uv[:, 1]).astype(int), np.rint(uv[:, 0]).astype(int)]
    return uv[np.isfinite(z) & (z > 1.0) & (z < 4.0)][:n]
