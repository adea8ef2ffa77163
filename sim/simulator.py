"""Closed-loop simulation: a unicycle robot with a head-mounted RGB-D camera in a `World`.

Frames: `base_link` (x forward, y left, z up) on the ground plane (z = 0); the camera
optical frame (x right, y down, z forward) is mounted at `T_base_camera`
(`camera_forward` m ahead, `camera_height` m up, pitched down by `camera_tilt_deg`),
like a legged robot's head camera. While walking the body bobs (small roll/pitch and
height oscillation at the gait frequency); ground truth includes it, odometry does not.

`Simulator.step(v, omega, dt)` integrates unicycle kinematics at the odometry rate,
stops at walls/boxes (`collided`), emits drift-model odometry
(`pipelines.odometry_drift.IncrementalDrift`) at every odometry tick and renders a
frame when a camera tick falls in the step.

Example (closed loop)::

    world = load_world("office")
    sim = Simulator(world, SimParams(), seed=0)
    step = sim.reset(world.goal_places["room_00"])        # 4x4 T_world_base
    while ...:
        step = sim.step(v=0.4, omega=0.1, dt=1 / 15)       # -> SimStep
        step.frame, step.odometry, step.ground_truth, step.collided
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numpy.typing import NDArray

from litevloc.base.geometry import GeometryError, PinholeIntrinsics, invert, make_T, so3_exp
from litevloc.base.params.sim import RealismParams, SimParams
from litevloc.hw.messages import GroundTruthPose, Odometry, RgbdFrame
from litevloc.pipelines.odometry_drift import IncrementalDrift
from litevloc.sim.people import composite
from litevloc.sim.realism import Lighting, apply_color, apply_depth, sample_lighting
from litevloc.sim.render import Renderer
from litevloc.sim.world import World


def bob_transform(t_s: float, speed_frac: float, params: SimParams) -> NDArray[np.float64]:
    """Body oscillation of a walking legged robot (4x4, applied between base and camera)."""
    if speed_frac <= 0 or (params.bob_deg == 0 and params.bob_height == 0):
        return np.eye(4)
    ph = 2 * np.pi * params.gait_hz * t_s
    a = np.radians(params.bob_deg) * min(speed_frac, 1.0)
    R = so3_exp(np.array([a * np.sin(ph), 0.6 * a * np.sin(2 * ph + 0.5), 0.0]))
    return make_T(
        R, np.array([0.0, 0.0, params.bob_height * min(speed_frac, 1.0) * np.sin(2 * ph)])
    )


@lru_cache(maxsize=16)
def _T_base_camera(params: SimParams) -> NDArray[np.float64]:
    T = params.T_base_camera
    T.setflags(write=False)
    return T


def camera_pose(
    T_world_base: NDArray[np.float64], t_s: float, speed: float, params: SimParams
) -> NDArray[np.float64]:
    """Ground-truth T_world_camera for a base pose (with gait bobbing at this speed)."""
    return (
        T_world_base
        @ bob_transform(t_s, abs(speed) / params.max_speed, params)
        @ _T_base_camera(params)
    )


def base_pose(x: float, y: float, yaw: float) -> NDArray[np.float64]:
    c, s = np.cos(yaw), np.sin(yaw)
    T = np.eye(4)
    T[:2, :2] = [[c, -s], [s, c]]
    T[:2, 3] = x, y
    return T


@dataclass(frozen=True, eq=False)
class SimStep:
    """Result of `Simulator.reset` / `step`."""

    t_ns: int
    frame: RgbdFrame | None  # rendered when a camera tick fell in this step (and colour was asked for)
    odometry: list[Odometry]  # at the odometry rate, since the last step
    ground_truth: GroundTruthPose  # camera pose at t_ns
    collided: bool
    T_world_base: NDArray[np.float64]
    depth: NDArray[np.float32] | None = None  # the camera tick's degraded depth (also in depth-only steps)


class Simulator:
    """Closed-loop simulator (see module docstring).

    Args:
        world: the world.
        params: robot/camera parameters.
        seed: seeds the odometry drift, the lighting of this run and per-frame noise.
        lighting: fixed lighting (default: drawn from `params.realism` with the seed).
        render: False skips rendering (kinematics, odometry and ground truth only).
    """

    def __init__(
        self,
        world: World,
        params: SimParams,
        seed: int,
        lighting: Lighting | None = None,
        render: bool = True,
    ) -> None:
        self.world = world
        self.params = params
        self.seed = int(seed)
        self.renderer = Renderer(world) if render else None
        self.K = params.intrinsics
        self.lighting = lighting or sample_lighting(
            params.realism, np.random.default_rng([self.seed, 11])
        )
        self._odom_period = round(1e9 / params.odometry_rate_hz)
        self._cam_period = round(1e9 / params.camera_rate_hz)
        self._state: tuple[float, float, float] | None = None

    # ---------------------------------------------------------------- state
    @property
    def T_world_base(self) -> NDArray[np.float64]:
        if self._state is None:
            raise RuntimeError("call reset() first")
        return base_pose(*self._state)

    @property
    def state(self) -> tuple[float, float, float]:
        """Ground-plane pose (x, y, yaw) of the robot; `reset()` must have been called."""
        if self._state is None:
            raise RuntimeError("call reset() first")
        return self._state

    def reset(self, T_world_base: NDArray[np.floating], t_ns: int = 0) -> SimStep:
        """Place the robot (pose on the ground plane; only x, y and yaw are used)."""
        T = np.asarray(T_world_base, dtype=np.float64)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise GeometryError("T_world_base must be a finite 4x4 matrix")
        x, y = float(T[0, 3]), float(T[1, 3])
        yaw = float(np.arctan2(T[1, 0], T[0, 0]))
        if not self.world.is_free(np.array([x, y]), self.params.robot_radius):
            raise GeometryError(
                f"start pose ({x:.2f}, {y:.2f}) is not free for radius {self.params.robot_radius} m"
            )
        self._state = (x, y, yaw)
        self._t_ns = int(t_ns)
        self._speed = 0.0
        self._frame_index = 0
        self._drift = IncrementalDrift(self.params.drift, self.seed)
        self._last_odom_T = self.T_world_base
        odom = [Odometry(self._t_ns, np.eye(4))]
        frame = self._render(self._t_ns)
        return SimStep(self._t_ns, frame, odom, self._gt(self._t_ns), False, self.T_world_base,
                       None if frame is None else frame.depth)

    def step(self, v: float, omega: float, dt: float, color: bool = True) -> SimStep:
        """Drive with forward speed v (m/s) and yaw rate omega (rad/s) for dt seconds.

        Odometry is returned for every odometry tick in the step; a frame is rendered at
        the last camera tick in the step (step at <= 1/camera_rate to get every frame).
        `color=False` renders only the depth of that tick (`SimStep.depth`, `frame` None):
        no texture sampling, shading or colour noise, for steps whose image nobody reads.
        """
        if self._state is None:
            raise RuntimeError("call reset() first")
        if not (np.isfinite(v) and np.isfinite(omega) and np.isfinite(dt)) or dt <= 0 or dt > 10:
            raise ValueError(f"need finite v, omega and 0 < dt <= 10 s, got {v}, {omega}, {dt}")
        p = self.params
        v = float(np.clip(v, -p.max_speed, p.max_speed))
        omega = float(np.clip(omega, -p.max_omega, p.max_omega))
        t_end = self._t_ns + round(dt * 1e9)
        odoms: list[Odometry] = []
        frame_t: int | None = None
        frame_state, frame_speed = self._state, self._speed
        frame: RgbdFrame | None = None
        collided = False
        t = self._t_ns
        while t < t_end:
            next_odom = (t // self._odom_period + 1) * self._odom_period
            next_cam = (t // self._cam_period + 1) * self._cam_period
            t_next = min(next_odom, next_cam, t_end)
            h = (t_next - t) * 1e-9
            if not collided:
                x, y, yaw = self._state
                mid = yaw + 0.5 * omega * h
                nx, ny = x + v * h * np.cos(mid), y + v * h * np.sin(mid)
                if self.world.is_free(np.array([nx, ny]), p.robot_radius):
                    self._state = (float(nx), float(ny), float(yaw + omega * h))
                    self._speed = v
                else:
                    collided = True
                    self._speed = 0.0
            t = t_next
            self._t_ns = t
            if t == next_odom:
                T_now = self.T_world_base
                D = invert(self._last_odom_T) @ T_now
                odoms.append(Odometry(t, self._drift.step(D, self._odom_period * 1e-9)))
                self._last_odom_T = T_now
            if t == next_cam:
                frame_t, frame_state, frame_speed = t, self._state, self._speed
        depth: NDArray[np.float32] | None = None
        if frame_t is not None:
            now = (self._state, self._speed)
            self._state, self._speed = frame_state, frame_speed
            if color:
                frame = self._render(frame_t)
                depth = None if frame is None else frame.depth
            else:
                depth = self._render_depth(frame_t)
            self._state, self._speed = now
        return SimStep(self._t_ns, frame, odoms, self._gt(self._t_ns), collided, self.T_world_base, depth)

    # ------------------------------------------------------------ internals
    def _gt(self, t_ns: int) -> GroundTruthPose:
        T = camera_pose(self.T_world_base, t_ns * 1e-9, self._speed, self.params)
        return GroundTruthPose(t_ns, T, self._frame_index)

    def _render_depth(self, t_ns: int) -> NDArray[np.float32] | None:
        """Depth-only tick: same pose, frame counter and per-frame seed as `_render`."""
        if self.renderer is None:
            return None
        T = camera_pose(self.T_world_base, t_ns * 1e-9, self._speed, self.params)
        depth = self.renderer.render_depth(T, self.K)
        add_people(self.world, T, self.K, t_ns, None, depth)
        rng = np.random.default_rng([self.seed, 13, self._frame_index])
        self._frame_index += 1
        return apply_depth(depth, self.params.realism, rng)

    def _render(self, t_ns: int) -> RgbdFrame | None:
        if self.renderer is None:
            return None
        T = camera_pose(self.T_world_base, t_ns * 1e-9, self._speed, self.params)
        frame = render_frame(
            self.renderer,
            T,
            self.K,
            self.params.realism,
            self.lighting,
            np.random.default_rng([self.seed, 13, self._frame_index]),
            t_ns,
            self._frame_index,
        )
        self._frame_index += 1
        return frame


def add_people(world: World, T_world_camera: NDArray[np.float64], K: PinholeIntrinsics, t_ns: int,
               color: NDArray[np.uint8] | None, depth: NDArray[np.float32]) -> None:
    """Composite the people of a changed world (`World.people`) into an ideal frame in place."""
    if world.people is not None:
        composite(world.people.at(t_ns * 1e-9, T_world_camera, world), T_world_camera, K, color, depth)


def render_frame(
    renderer: Renderer,
    T_world_camera: NDArray[np.float64],
    K: PinholeIntrinsics,
    realism: RealismParams,
    lighting: Lighting,
    rng: np.random.Generator,
    t_ns: int,
    index: int,
) -> RgbdFrame:
    """Render one degraded RGB-D frame at a camera pose."""
    color, depth = renderer.render(T_world_camera, K)
    add_people(renderer.world, T_world_camera, K, t_ns, color, depth)
    color = apply_color(color, lighting, realism, rng)
    depth = apply_depth(depth, realism, rng)
    return RgbdFrame(t_ns, color, depth, K.K, index=index)


__all__ = [
    "SimParams",
    "SimStep",
    "Simulator",
    "add_people",
    "base_pose",
    "bob_transform",
    "camera_pose",
    "render_frame",
]
