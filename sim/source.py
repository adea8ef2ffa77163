"""`SimSequenceSource`: a simulated pass through a world as a `StreamSource`.

The pass is driven first without rendering (`trajectory.follow`: ground truth and
drift odometry at the odometry rate); frames are rendered lazily at the camera rate
while iterating, so `McapRecorder` records it and the rest of the system reads it like
any recording. Messages come in time order; at equal stamps odometry comes first, then
the frame, then its ground-truth pose.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
from numpy.typing import NDArray

from litevloc.base.geometry import interpolate_pose_at
from litevloc.base.params.sim import SimParams
from litevloc.hw.messages import GroundTruthPose, Message, Odometry, RgbdFrame, StreamStats
from litevloc.sim.realism import Lighting, sample_lighting
from litevloc.sim.render import Renderer
from litevloc.sim.simulator import add_people, camera_pose, render_frame
from litevloc.sim.trajectory import (
    PASS_NAMES,
    FollowResult,
    PassName,
    follow,
    is_pass_name,
    pass_tasks,
)
from litevloc.sim.world import World


class SimSequenceSource:
    """A map or query pass of `world` (see module docstring).

    Args:
        world: the world.
        pass_name: "map" (visits every room, full turns), "query" (other order, spots and
            lighting) or "loop" (laps the ring corridor of a layout-"loop" world).
        seed: seeds the route (query), lighting, odometry drift and image noise.
        duration: seconds to simulate at most (None = the whole pass).
        params: robot/camera parameters.
    """

    def __init__(
        self,
        world: World,
        pass_name: PassName,
        seed: int,
        duration: float | None = None,
        params: SimParams | None = None,
    ) -> None:
        if pass_name not in PASS_NAMES:
            raise ValueError(f"pass must be one of {PASS_NAMES}, got {pass_name!r}")
        if duration is not None and not (duration > 0):
            raise ValueError(f"duration must be > 0 s, got {duration}")
        self.world = world
        self.pass_name: PassName = pass_name
        self.seed = int(seed)
        self.params = params or SimParams()
        self.name = f"sim:{world.spec.name}:{pass_name}:seed{seed}"
        self.stats = StreamStats()
        k = PASS_NAMES.index(pass_name)
        seq_seed = self.seed * 3 + k if k < 3 else 10_000 + self.seed * 8 + k  # first three: as before
        self.lighting: Lighting = sample_lighting(
            self.params.realism, np.random.default_rng([seq_seed, 11])
        )
        self._noise_seed = seq_seed
        start, tasks = pass_tasks(world, pass_name, self.seed, self.params)
        self.run: FollowResult = follow(world, self.params, seq_seed, start, tasks, duration)
        t = self.run.t_ns
        period = round(1e9 / self.params.camera_rate_hz)
        self.frame_times: NDArray[np.int64] = np.arange(0, int(t[-1]) + 1, period, dtype=np.int64)
        self._renderer: Renderer | None = None

    def frame_count(self) -> int:
        return len(self.frame_times)

    @property
    def duration_s(self) -> float:
        return float(self.run.t_ns[-1]) * 1e-9

    def camera_poses(self) -> NDArray[np.float64]:
        """(F, 4, 4) ground-truth T_world_camera at the frame times."""
        return np.stack([self._cam_pose(int(t)) for t in self.frame_times])

    def _cam_pose(self, t_ns: int) -> NDArray[np.float64]:
        T_base = interpolate_pose_at(t_ns, self.run.t_ns, self.run.T_world_base)
        k = min(int(np.searchsorted(self.run.t_ns, t_ns)), len(self.run.speed) - 1)
        return camera_pose(T_base, t_ns * 1e-9, float(self.run.speed[k]), self.params)

    def frame(self, index: int) -> RgbdFrame:
        """Render frame `index` (deterministic: same seed -> identical arrays)."""
        self.prepare_renderer()
        assert self._renderer is not None
        t = int(self.frame_times[index])
        return render_frame(
            self._renderer,
            self._cam_pose(t),
            self.params.intrinsics,
            self.params.realism,
            self.lighting,
            np.random.default_rng([self._noise_seed, 13, index]),
            t,
            index,
        )

    def depth(self, index: int) -> NDArray[np.float32]:
        """Degraded depth of frame `index` alone (no texturing, shading or colour noise):
        for consumers that need geometry only, e.g. pass 1 of a map build. Deterministic;
        the noise realisation differs from `frame(index).depth` (colour noise draws first)."""
        from litevloc.sim.realism import apply_depth

        self.prepare_renderer()
        assert self._renderer is not None
        t = int(self.frame_times[index])
        T = self._cam_pose(t)
        d = self._renderer.render_depth(T, self.params.intrinsics)
        add_people(self.world, T, self.params.intrinsics, t, None, d)
        return apply_depth(d, self.params.realism, np.random.default_rng([self._noise_seed, 13, index]))

    def prepare_renderer(self) -> None:
        """Build the renderer now (seconds in a large world): before a replay paced in real time
        starts its clock, or before worker processes fork so that they share it."""
        if self._renderer is None:
            self._renderer = Renderer(self.world)

    def __iter__(self) -> Iterator[Message]:
        return self.messages()

    def messages(self, frames: Iterator[RgbdFrame] | None = None) -> Iterator[Message]:
        """The pass's messages in time order. `frames`: the rendered frames in index order from
        elsewhere (e.g. worker processes, `frame(i)` for i = 0, 1, ...); None renders them here."""
        self.prepare_renderer()
        odo_t, odo_T = self.run.t_ns, self.run.T_odom_base
        k = 0
        for i, t in enumerate(self.frame_times):
            while k < len(odo_t) and odo_t[k] <= t:
                self.stats.messages += 1
                yield Odometry(int(odo_t[k]), odo_T[k].copy())
                k += 1
            frame = self.frame(i) if frames is None else next(frames)
            if frame.index != i:
                raise ValueError(f"frames out of order: got frame {frame.index} where frame {i} belongs")
            self.stats.messages += 2
            yield frame
            yield GroundTruthPose(int(t), self._cam_pose(int(t)), index=i)
        while k < len(odo_t):
            self.stats.messages += 1
            yield Odometry(int(odo_t[k]), odo_T[k].copy())
            k += 1


def open_sim_source(uri: str, params: SimParams | None = None) -> SimSequenceSource:
    """`sim:WORLD[?pass=map|query|loop&seed=N&duration=S&world_seed=M]` -> a sequence source.

    WORLD is a shipped world name or a YAML path, e.g. `sim:office?pass=query&seed=2`.
    ValueError (naming the problem) on a malformed URI.
    """
    from urllib.parse import parse_qs, urlsplit

    from litevloc.sim.world import load_world

    if not uri.startswith("sim:"):
        raise ValueError(f"simulator source must look like sim:WORLD?pass=map&seed=0, got {uri!r}")
    parts = urlsplit(uri[4:])
    world_name = parts.path
    if not world_name:
        raise ValueError(f"{uri!r}: no world named (sim:WORLD...)")
    query = {k: v[-1] for k, v in parse_qs(parts.query, strict_parsing=bool(parts.query)).items()}
    unknown = sorted(set(query) - {"pass", "seed", "duration", "world_seed"})
    if unknown:
        raise ValueError(
            f"{uri!r}: unknown option(s) {unknown}; allowed: pass, seed, duration, world_seed"
        )
    try:
        seed = int(query.get("seed", "0"))
        duration = float(query["duration"]) if "duration" in query else None
        world_seed = int(query["world_seed"]) if "world_seed" in query else None
    except ValueError as exc:
        raise ValueError(f"{uri!r}: {exc}") from exc
    pass_name = query.get("pass", "map")
    if not is_pass_name(pass_name):
        raise ValueError(f"{uri!r}: pass must be one of {PASS_NAMES}")
    return SimSequenceSource(
        load_world(world_name, seed=world_seed), pass_name, seed, duration, params
    )
