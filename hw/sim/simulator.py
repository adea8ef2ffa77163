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
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from litevloc.hw.messages import GroundTruthPose, Odometry, RgbdFrame
from litevloc.hw.sim.realism import Lighting, RealismParams, apply_color, apply_depth, sample_lighting
from litevloc.hw.sim.render import Renderer
from litevloc.hw.sim.world import World
from litevloc.pipelines.geometry import GeometryError, PinholeIntrinsics, invert, make_T, so3_exp
from litevloc.pipelines.odometry_drift import R_BASE_OPTICAL, DriftParams, IncrementalDrift


@dataclass(frozen=True)
class SimParams:
    """Robot, camera and sensor-rate parameters of the simulator."""

    width: int = 320
    height: int = 240
    hfov_deg: float = 72.0
    camera_height: float = 0.5
    camera_forward: float = 0.25
    camera_tilt_deg: float = 5.0  # pitch down
    camera_rate_hz: float = 15.0
    odometry_rate_hz: float = 200.0
    robot_radius: float = 0.3
    max_speed: float = 1.0  # m/s, commands are clipped
    max_omega: float = 1.5  # rad/s
    cruise_speed: float = 0.5  # waypoint follower
    cruise_omega: float = 0.6
    bob_deg: float = 0.6  # roll/pitch amplitude at max_speed
    bob_height: float = 0.01  # m
    gait_hz: float = 2.0
    drift: DriftParams = field(default_factory=DriftParams)
    realism: RealismParams = field(default_factory=RealismParams)

    def __post_init__(self) -> None:
        if not (16 <= self.width <= 4096 and 16 <= self.height <= 4096):
            raise ValueError(f"image size must be in [16, 4096], got {self.width}x{self.height}")
        if not (20 <= self.hfov_deg <= 150):
            raise ValueError(f"hfov_deg must be in [20, 150], got {self.hfov_deg}")
        if not (0.05 <= self.camera_height <= 2.0):
            raise ValueError(f"camera_height must be in [0.05, 2] m, got {self.camera_height}")
        if not (-30 <= self.camera_tilt_deg <= 30):
            raise ValueError(f"camera_tilt_deg must be in [-30, 30], got {self.camera_tilt_deg}")
        if not (0 < self.camera_rate_hz <= 120) or not (0 < self.odometry_rate_hz <= 2000):
            raise ValueError("camera_rate_hz must be in (0, 120] and odometry_rate_hz in (0, 2000]")
        if self.odometry_rate_hz < self.camera_rate_hz:
            raise ValueError("odometry_rate_hz must be >= camera_rate_hz")
        for name in ("robot_radius", "max_speed", "max_omega", "cruise_speed", "cruise_omega", "gait_hz"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0")
        if self.cruise_speed > self.max_speed or self.cruise_omega > self.max_omega:
            raise ValueError("cruise_speed/cruise_omega must not exceed max_speed/max_omega")
        if self.bob_deg < 0 or self.bob_height < 0:
            raise ValueError("bob_deg and bob_height must be >= 0")

    @property
    def intrinsics(self) -> PinholeIntrinsics:
        fx = (self.width / 2) / np.tan(np.radians(self.hfov_deg) / 2)
        return PinholeIntrinsics(fx, fx, (self.width - 1) / 2, (self.height - 1) / 2, self.width, self.height)

    @property
    def T_base_camera(self) -> NDArray[np.float64]:
        """4x4 pose of the camera optical frame in base_link (tilted down by camera_tilt_deg)."""
        tilt = np.radians(self.camera_tilt_deg)
        R_pitch = so3_exp(np.array([0.0, tilt, 0.0]))  # +pitch about base y tilts x (forward) down
        return make_T(R_pitch @ R_BASE_OPTICAL, np.array([self.camera_forward, 0.0, self.camera_height]))


def bob_transform(t_s: float, speed_frac: float, params: SimParams) -> NDArray[np.float64]:
    """Body oscillation of a walking legged robot (4x4, applied between base and camera)."""
    if speed_frac <= 0 or (params.bob_deg == 0 and params.bob_height == 0):
        return np.eye(4)
    ph = 2 * np.pi * params.gait_hz * t_s
    a = np.radians(params.bob_deg) * min(speed_frac, 1.0)
    R = so3_exp(np.array([a * np.sin(ph), 0.6 * a * np.sin(2 * ph + 0.5), 0.0]))
    return make_T(R, np.array([0.0, 0.0, params.bob_height * min(speed_frac, 1.0) * np.sin(2 * ph)]))


def camera_pose(T_world_base: NDArray[np.float64], t_s: float, speed: float, params: SimParams) -> NDArray[np.float64]:
    """Ground-truth T_world_camera for a base pose (with gait bobbing at this speed)."""
    return T_world_base @ bob_transform(t_s, abs(speed) / params.max_speed, params) @ params.T_base_camera


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
    frame: RgbdFrame | None  # rendered when a camera tick fell in this step
    odometry: list[Odometry]  # at the odometry rate, since the last step
    ground_truth: GroundTruthPose  # camera pose at t_ns
    collided: bool
    T_world_base: NDArray[np.float64]


class Simulator:
    """Closed-loop simulator (see module docstring).

    Args:
        world: the world.
        params: robot/camera parameters.
        seed: seeds the odometry drift, the lighting of this run and per-frame noise.
        lighting: fixed lighting (default: drawn from `params.realism` with the seed).
        render: False skips rendering (kinematics, odometry and ground truth only).
    """

    def __init__(self, world: World, params: SimParams, seed: int, lighting: Lighting | None = None,
                 render: bool = True) -> None:
        self.world = world
        self.params = params
        self.seed = int(seed)
        self.renderer = Renderer(world) if render else None
        self.K = params.intrinsics
        self.lighting = lighting or sample_lighting(params.realism, np.random.default_rng([self.seed, 11]))
        self._odom_period = int(round(1e9 / params.odometry_rate_hz))
        self._cam_period = int(round(1e9 / params.camera_rate_hz))
        self._state: tuple[float, float, float] | None = None

    # ---------------------------------------------------------------- state
    @property
    def T_world_base(self) -> NDArray[np.float64]:
        if self._state is None:
            raise RuntimeError("call reset() first")
        return base_pose(*self._state)

    def reset(self, T_world_base: NDArray[np.floating], t_ns: int = 0) -> SimStep:
        """Place the robot (pose on the ground plane; only x, y and yaw are used)."""
        T = np.asarray(T_world_base, dtype=np.float64)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise GeometryError("T_world_base must be a finite 4x4 matrix")
        x, y = float(T[0, 3]), float(T[1, 3])
        yaw = float(np.arctan2(T[1, 0], T[0, 0]))
        if not self.world.is_free(np.array([x, y]), self.params.robot_radius):
            raise GeometryError(f"start pose ({x:.2f}, {y:.2f}) is not free for radius {self.params.robot_radius} m")
        self._state = (x, y, yaw)
        self._t_ns = int(t_ns)
        self._speed = 0.0
        self._frame_index = 0
        self._drift = IncrementalDrift(self.params.drift, self.seed)
        self._last_odom_T = self.T_world_base
        odom = [Odometry(self._t_ns, np.eye(4))]
        frame = self._render(self._t_ns)
        return SimStep(self._t_ns, frame, odom, self._gt(self._t_ns), False, self.T_world_base)

    def step(self, v: float, omega: float, dt: float) -> SimStep:
        """Drive with forward speed v (m/s) and yaw rate omega (rad/s) for dt seconds."""
        if self._state is None:
            raise RuntimeError("call reset() first")
        if not (np.isfinite(v) and np.isfinite(omega) and np.isfinite(dt)) or dt <= 0 or dt > 10:
            raise ValueError(f"need finite v, omega and 0 < dt <= 10 s, got {v}, {omega}, {dt}")
        p = self.params
        v = float(np.clip(v, -p.max_speed, p.max_speed))
        omega = float(np.clip(omega, -p.max_omega, p.max_omega))
        t_end = self._t_ns + int(round(dt * 1e9))
        odoms: list[Odometry] = []
        frame_t: int | None = None
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
                frame_t = t
                frame = self._render(t)
        del frame_t
        return SimStep(self._t_ns, frame, odoms, self._gt(self._t_ns), collided, self.T_world_base)

    # ------------------------------------------------------------ internals
    def _gt(self, t_ns: int) -> GroundTruthPose:
        T = camera_pose(self.T_world_base, t_ns * 1e-9, self._speed, self.params)
        return GroundTruthPose(t_ns, T, self._frame_index)

    def _render(self, t_ns: int) -> RgbdFrame | None:
        if self.renderer is None:
            return None
        T = camera_pose(self.T_world_base, t_ns * 1e-9, self._speed, self.params)
        frame = render_frame(self.renderer, T, self.K, self.params.realism, self.lighting,
                             np.random.default_rng([self.seed, 13, self._frame_index]), t_ns, self._frame_index)
        self._frame_index += 1
        return frame


def render_frame(renderer: Renderer, T_world_camera: NDArray[np.float64], K: PinholeIntrinsics,
                 realism: RealismParams, lighting: Lighting, rng: np.random.Generator, t_ns: int,
                 index: int) -> RgbdFrame:
    """Render one degraded RGB-D frame at a camera pose."""
    color, depth = renderer.render(T_world_camera, K)
    color = apply_color(color, lighting, realism, rng)
    depth = apply_depth(depth, realism, rng)
    return RgbdFrame(t_ns, color, depth, K.K, index=index)
