"""A synthetic robot for the SLAM core: landmarks on a room's walls, a camera on a base_link
driving laps, drifting odometry, and model doubles that see exactly the landmarks (no ONNX).

Every landmark has a unique random descriptor; `extract` returns the landmarks a frame sees
(projected, with pixel noise), the frame's depth image holds each landmark's depth in a small
patch around its pixel, `match` pairs identical landmarks (mutual nearest descriptors), and
`describe` is a place descriptor of the camera's position and heading (similar at revisits).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from litevloc.base.geometry import invert, make_T, so3_exp
from litevloc.pipelines.odometry_drift import simulate_odometry
from litevloc.pipelines.slam.session import SlamResult, SlamSession
from litevloc.pipelines.slam.types import FrameImages, FrameRef, SlamModels
from litevloc.pipelines.topomap.types import NodeFeatures

W, H = 320, 240
K = np.array([[220.0, 0.0, 159.5], [0.0, 220.0, 119.5], [0.0, 0.0, 1.0]])
# camera optical frame on base_link: 0.2 m forward, 0.5 m up, looking along base x
T_BASE_CAMERA = make_T(np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]), np.array([0.2, 0.0, 0.5]))
F64 = NDArray[np.float64]


def _room_landmarks(rng: np.random.Generator, half: float, n_per_wall: int) -> F64:
    """Points on the four walls of a square room (|x|, |y| = half) between 0.1 and 2 m high."""
    pts = []
    for axis, sign in ((0, 1), (0, -1), (1, 1), (1, -1)):
        p = np.zeros((n_per_wall, 3))
        p[:, axis] = sign * half
        p[:, 1 - axis] = rng.uniform(-half, half, n_per_wall)
        p[:, 2] = rng.uniform(0.1, 2.0, n_per_wall)
        pts.append(p)
    return np.concatenate(pts)


def lap_poses(n: int, radius: float, laps: float) -> F64:
    """(n, 4, 4) base_link poses driving `laps` counter-clockwise laps of a circle (z = 0)."""
    a = np.linspace(0.0, 2 * np.pi * laps, n)
    out = np.zeros((n, 4, 4))
    for k, ang in enumerate(a):
        out[k] = make_T(so3_exp(np.array([0.0, 0.0, ang + np.pi / 2])), np.array([radius * np.cos(ang),
                                                                                   radius * np.sin(ang), 0.0]))
    return out


@dataclass
class Scene:
    """Landmarks, true base poses and stamps of the frames, odometry, and the doubles."""

    landmarks: F64
    desc: NDArray[np.float32]
    T_world_base: F64
    t_ns: NDArray[np.int64]
    odom_t: NDArray[np.int64]
    odom_T: F64
    pixel_noise: float = 0.3
    seed: int = 0
    # frame index -> where its image appears taken from (camera-frame offset, m): an aliased view
    aliased: dict[int, F64] = field(default_factory=dict)
    _seen: dict[int, tuple[NodeFeatures, NDArray[np.float32]]] = field(default_factory=dict)

    def T_world_camera(self, i: int) -> F64:
        return self.T_world_base[i] @ T_BASE_CAMERA

    def images(self, i: int) -> FrameImages:
        """A frame's 'images': the colour array only carries the frame number (its first pixel
        row) for the doubles; depth has the landmarks' depth around their pixels."""
        color = np.zeros((H, W, 3), np.uint8)
        color[0, :4, 0] = np.frombuffer(np.int32(i).tobytes(), np.uint8)
        depth = self._view(i)[1]
        return FrameImages(color, depth, b"jpeg")

    def _view(self, i: int) -> tuple[NodeFeatures, NDArray[np.float32]]:
        if i not in self._seen:
            rng = np.random.default_rng([self.seed, i])
            Tcw = invert(self.T_world_camera(i) @ make_T(np.eye(3), self.aliased.get(i, np.zeros(3))))
            pc = self.landmarks @ Tcw[:3, :3].T + Tcw[:3, 3]
            front = (pc[:, 2] > 0.3) & (pc[:, 2] < 8.0)
            uv = np.full((len(pc), 2), -1.0)
            uv[front] = pc[front, :2] / pc[front, 2:3] * [K[0, 0], K[1, 1]] + K[:2, 2]
            ok = front & (uv[:, 0] > 3) & (uv[:, 0] < W - 4) & (uv[:, 1] > 3) & (uv[:, 1] < H - 4)
            idx = np.nonzero(ok)[0]
            kp = (uv[idx] + rng.normal(0, self.pixel_noise, (len(idx), 2))).astype(np.float32)
            depth = np.full((H, W), np.nan, np.float32)
            for (u, v), z in zip(np.round(uv[idx]).astype(int), pc[idx, 2], strict=True):
                depth[v - 2: v + 3, u - 2: u + 3] = z
            d = self.desc[idx] + rng.normal(0, 0.02, (len(idx), self.desc.shape[1])).astype(np.float32)
            self._seen[i] = (NodeFeatures(kp, d.astype(np.float32), np.ones(len(idx), np.float32), (W, H)), depth)
        return self._seen[i]

    def frame_ref(self, i: int) -> FrameRef:
        return FrameRef(int(self.t_ns[i]), i, K, lambda i=i: self.images(i))

    def models(self) -> SlamModels:
        def index(color: NDArray[np.uint8]) -> int:
            return int(np.frombuffer(color[0, :4, 0].tobytes(), np.int32)[0])

        def extract(color: NDArray[np.uint8]) -> NodeFeatures:
            return self._view(index(color))[0]

        def describe(color: NDArray[np.uint8]) -> NDArray[np.float32]:
            T = self.T_world_camera(index(color))
            look = T[:3, 2]
            v = np.concatenate([T[:2, 3] / 2.0, 2.0 * look[:2]])
            anchors = np.stack(np.meshgrid(np.linspace(-2, 2, 5), np.linspace(-2, 2, 5), np.linspace(-2, 2, 3),
                                           np.linspace(-2, 2, 3)), -1).reshape(-1, 4)
            out = np.exp(-np.sum((anchors - v) ** 2, axis=1) / 0.5).astype(np.float32)
            return out / np.linalg.norm(out)

        def match(a: NodeFeatures, b: NodeFeatures) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
            if len(a.descriptors) == 0 or len(b.descriptors) == 0:
                return np.zeros(0, np.int64), np.zeros(0, np.int64)
            s = np.asarray(a.descriptors) @ np.asarray(b.descriptors).T
            ab, ba = np.argmax(s, 1), np.argmax(s, 0)
            i = np.nonzero((ba[ab] == np.arange(len(ab))) & (s[np.arange(len(ab)), ab] > 0.8))[0]
            return i.astype(np.int64), ab[i].astype(np.int64)

        return SlamModels(extract, describe, match, match)


def make_scene(n_frames: int = 300, laps: float = 1.25, seed: int = 0, radius: float = 1.8) -> Scene:
    """A robot driving `laps` laps of a circle in a 6 m room, 15 frames per second, with
    100 Hz drifting odometry (the project's drift model, seeded)."""
    rng = np.random.default_rng(seed)
    lm = _room_landmarks(rng, 3.0, 500)
    desc = rng.normal(size=(len(lm), 32)).astype(np.float32)
    desc /= np.linalg.norm(desc, axis=1, keepdims=True)
    T = lap_poses(n_frames, radius, laps)
    t = (np.arange(n_frames) * (1e9 / 15)).astype(np.int64)
    odo_t, odo_T = simulate_odometry(t, T, 100.0, _drift(), seed)
    return Scene(lm, desc, T, t, odo_t, odo_T, seed=seed)


def _drift():  # type: ignore[no-untyped-def]
    from litevloc.base.params.drift import DriftParams

    return DriftParams(sigma_trans_per_m=0.02, sigma_rot_per_m=float(np.radians(1.0)),
                       yaw_bias_per_m=float(np.radians(2.0)))


def run_session(scene: Scene, cfg: Any = None, odometry: bool = True,
                drop_odometry_s: tuple[float, float] | None = None, drop_frames_s: tuple[float, float] | None = None,
                odometry_shift: Callable[[float], float] | None = None) -> tuple[SlamSession, SlamResult]:
    """Feed the scene to a `SlamSession` in time order (one BLAS thread, as `map build`), with
    faults: odometry samples dropped in a window, frames dropped in a window, or the odometry
    moved along its frame's x axis by `odometry_shift(t_s)` metres."""
    from threadpoolctl import threadpool_limits

    from litevloc.config import load_config

    cfg = cfg or load_config("default")
    s = SlamSession(cfg.slam, cfg.mapping, cfg.localization, scene.models(), T_BASE_CAMERA, odometry)

    def inside(t_ns: int, w: tuple[float, float] | None) -> bool:
        return w is not None and w[0] <= t_ns * 1e-9 < w[1]

    with threadpool_limits(limits=1, user_api="blas"):
        k = 0
        for i in range(len(scene.t_ns)):
            while odometry and k < len(scene.odom_t) and scene.odom_t[k] <= scene.t_ns[i]:
                t = int(scene.odom_t[k])
                if not inside(t, drop_odometry_s):
                    T = scene.odom_T[k].copy()
                    if odometry_shift is not None:
                        T = make_T(np.eye(3), np.array([odometry_shift(t * 1e-9), 0.0, 0.0])) @ T
                    s.add_odometry(t, T)
                k += 1
            if not inside(int(scene.t_ns[i]), drop_frames_s):
                s.add_frame(scene.frame_ref(i))
        return s, s.finish()


def keyframe_ate(scene: Scene, res: SlamResult) -> float:
    """RMSE (m) of the mapped keyframes' positions against the truth after SE(3) alignment."""
    return keyframe_ate_of(scene, res, res.graph.poses)


def keyframe_ate_of(scene: Scene, res: SlamResult, poses: dict[int, F64]) -> float:
    """The same for keyframe `poses` (id -> T_map_camera) of `res`'s keyframes."""
    from litevloc.pipelines.evaluation.trajectory import ate

    ids = sorted(poses)
    est = np.stack([poses[i] for i in ids])
    ref = np.stack([scene.T_world_camera(res.keyframes[i].index) for i in ids])
    return float(ate(est, ref).rmse)
