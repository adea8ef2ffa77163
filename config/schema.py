"""The LiteVLoc configuration tree: typed, frozen dataclasses with their defaults.

This is the one place where defaults live. YAML presets in `config/presets/` override
them; `load_config` rejects unknown keys and wrong types, naming the key and file.
Sections own the parameters of one subsystem; their parameter classes live in the bottom
layer `litevloc.base.params` (re-exported next to their algorithm or driver), so importing
the configuration imports no algorithm or hardware module.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from litevloc.base.frames import parse_frames
from litevloc.base.geometry import make_T, quat_xyzw_to_matrix
from litevloc.base.params.calibration import ColorDepthCalibration
from litevloc.base.params.camera import CameraConfig
from litevloc.base.params.drift import DriftParams
from litevloc.base.params.fusion import FusionParams

# PENDING (issue 19): these two still live next to their algorithms, which other branches are
# editing; they move to litevloc.base.params after the merge. Until then importing the config
# pulls cv2 and scipy through them (tests/config/test_layers.py names them).
from litevloc.base.params.localization import LocalizationParams
from litevloc.base.params.mapping import MappingParams
from litevloc.base.params.models import ModelsConfig
from litevloc.base.params.navigation import GoalParams, OpeningParams, TrackerParams
from litevloc.base.params.odometry import OdometryCheckParams
from litevloc.base.params.sim import SimParams


@dataclass(frozen=True)
class SourceConfig:
    """Where sensor data come from when no `--source` is given on the command line."""

    kind: Literal["recording", "dataset", "oak-d", "sim"] = "recording"
    path: str = ""
    frames: str = ""  # Python slice over frame indices, as --frames
    strict: bool = False  # live/replay: count and skip bad messages instead of failing

    def __post_init__(self) -> None:
        if self.kind in ("recording", "dataset") and self.frames:
            parse_frames(self.frames)


@dataclass(frozen=True)
class OdometrySimConfig:
    """Simulated proprioceptive odometry for posed datasets that have none."""

    rate_hz: float = 100.0  # 0 = write no odometry
    seed: int = 0
    drift: DriftParams = field(default_factory=DriftParams)

    def __post_init__(self) -> None:
        if not (self.rate_hz >= 0 and self.rate_hz <= 2000):
            raise ValueError(f"rate_hz must be in [0, 2000], got {self.rate_hz}")


@dataclass(frozen=True)
class ReplayConfig:
    """Playback of recordings."""

    rate: float = 1.0  # real-time factor; 0 = as fast as possible

    def __post_init__(self) -> None:
        if not (self.rate >= 0):
            raise ValueError(f"rate must be >= 0, got {self.rate}")


@dataclass(frozen=True)
class FusionConfig:
    """Pose SLAM (VLoc + odometry fusion) and the camera extrinsics it needs.

    `base_camera_*`: pose of the camera optical frame in base_link (`T_base_camera`);
    the default is a camera at the base origin looking along base x (REP-103 body axes),
    as used for datasets where base_link is the camera.
    """

    params: FusionParams = field(default_factory=FusionParams)
    base_camera_translation: tuple[float, float, float] = (0.0, 0.0, 0.0)
    base_camera_quat_xyzw: tuple[float, float, float, float] = (-0.5, 0.5, -0.5, 0.5)

    def __post_init__(self) -> None:
        import math

        vals = (*self.base_camera_translation, *self.base_camera_quat_xyzw)
        if not all(math.isfinite(v) for v in vals):
            raise ValueError("base_camera_translation / base_camera_quat_xyzw must be finite")
        n = math.sqrt(sum(v * v for v in self.base_camera_quat_xyzw))
        if abs(n - 1.0) > 1e-3:
            raise ValueError(
                f"base_camera_quat_xyzw must be a unit quaternion (x, y, z, w), norm is {n:.6f}"
            )

    def T_base_camera(self) -> NDArray[np.float64]:
        """4x4 float64 T_base_camera from the configured translation and quaternion."""
        q, t = np.asarray(self.base_camera_quat_xyzw), np.asarray(self.base_camera_translation)
        return make_T(quat_xyzw_to_matrix(q), t)


@dataclass(frozen=True)
class LiteVLocConfig:
    """Root of the configuration tree."""

    name: str = "default"
    map: str = ""  # map folder the service localizes in (`litevloc run` / `replay --config`; --map overrides)
    source: SourceConfig = field(default_factory=SourceConfig)
    odometry_sim: OdometrySimConfig = field(default_factory=OdometrySimConfig)
    replay: ReplayConfig = field(default_factory=ReplayConfig)
    camera: CameraConfig = field(default_factory=CameraConfig)  # live OAK-D (source.kind: oak-d)
    models: ModelsConfig = field(default_factory=ModelsConfig)
    mapping: MappingParams = field(default_factory=MappingParams)
    localization: LocalizationParams = field(default_factory=LocalizationParams)
    fusion: FusionConfig = field(default_factory=FusionConfig)
    sim: SimParams = field(default_factory=SimParams)
    zenoh: ZenohConfig = field(default_factory=lambda: ZenohConfig())
    runtime: RuntimeConfig = field(default_factory=lambda: RuntimeConfig())
    # Colour camera of an RGB-D dataset whose depth is not registered (7-Scenes); None = as published.
    rgbd_calibration: ColorDepthCalibration | None = None
    planner: PlannerConfig = field(default_factory=lambda: PlannerConfig())
    diagnostics: DiagnosticsConfig = field(default_factory=lambda: DiagnosticsConfig())


# --------------------------------------------------------------------- runtime / Zenoh
# (appended for the runtime issue; the classes are used by litevloc.runtime.bus/service)
_ENDPOINT_PROTOCOLS = ("tcp", "udp", "tls", "quic", "unixsock-stream", "ws", "serial")


def _check_endpoint(ep: str, where: str) -> None:
    proto, sep, rest = ep.partition("/")
    if not sep or proto not in _ENDPOINT_PROTOCOLS or not rest:
        raise ValueError(
            f"{where} endpoint {ep!r} must look like tcp/127.0.0.1:7447 (protocol one of {list(_ENDPOINT_PROTOCOLS)})"
        )


@dataclass(frozen=True)
class ZenohConfig:
    """The Zenoh session: always explicit (Zenoh's own default listens on every interface
    and multicasts; ours listens on loopback only and does not scout).

    `tls`, `access_control` and `extra` are passed through to Zenoh's JSON5 config:
    `tls` goes to `transport/link/tls` (a mapping, or JSON5 text), `access_control` to
    `access_control`, and `extra` is a mapping {zenoh config key path: value} inserted
    last (e.g. {"transport/shared_memory/enabled": false}). See the Zenoh config reference.
    """

    mode: Literal["peer", "client"] = "peer"
    listen: tuple[str, ...] = ("tcp/127.0.0.1:7447",)  # ignored in client mode
    connect: tuple[str, ...] = ()
    multicast_scouting: bool = False
    connect_timeout_s: float = 3.0  # per attempt at start-up
    require_connect: bool = True  # start fails if no `connect` endpoint is reachable
    namespace: str = ""  # key prefix, e.g. "robot1" -> robot1/litevloc/pose
    attach_send_time: bool = True  # 8-byte little-endian monotonic send time (ns) as the Zenoh attachment
    tls: Any = None
    access_control: Any = None
    extra: Any = None

    def __post_init__(self) -> None:
        for ep in self.listen:
            _check_endpoint(ep, "zenoh.listen")
        for ep in self.connect:
            _check_endpoint(ep, "zenoh.connect")
        if self.mode == "client" and not self.connect:
            raise ValueError("zenoh.mode 'client' needs at least one zenoh.connect endpoint (a router)")
        if not (0 < self.connect_timeout_s <= 600):
            raise ValueError(f"zenoh.connect_timeout_s must be in (0, 600], got {self.connect_timeout_s}")
        ns = self.namespace
        if ns and (ns.startswith("/") or ns.endswith("/") or any(c in ns for c in "*$?#")):
            raise ValueError(f"zenoh.namespace {ns!r} must not start/end with '/' nor contain * $ ? #")
        for name in ("tls", "access_control", "extra"):
            v = getattr(self, name)
            if v is not None and not isinstance(v, str | dict):
                raise ValueError(f"zenoh.{name} must be a mapping or JSON5 text, got {type(v).__name__}")
        if self.extra is not None and not isinstance(self.extra, dict):
            raise ValueError("zenoh.extra must be a mapping {config key path: value}")


@dataclass(frozen=True)
class RuntimeConfig:
    """Threads, queues, status and tracking-loss policy of the onboard service."""

    # realtime: threads, latest-frame mailbox (stale frames dropped);
    # deterministic: threads in lockstep, every frame processed in order (tests, replay checks);
    # sequential: everything in the calling thread, in source order (the baseline).
    mode: Literal["realtime", "deterministic", "sequential"] = "realtime"
    odometry_queue_capacity: int = 4096
    result_queue_capacity: int = 64
    publish_queue_capacity: int = 4096
    # true: the fusion thread serialises and puts on Zenoh itself (one thread hand-off less per pose;
    # a Zenoh put does not wait for the network); false: through the outbox FIFO to a publisher thread
    publish_inline: bool = True
    # true: odometry that makes a fusion keyframe due is answered from the current estimate and the
    # smoother update (~1-3 ms, every fusion.keyframe_period_s = 5 % of 200 Hz odometry) runs after
    # the pose is handed on (published, with publish_inline); false: before, as the pose's own cost.
    defer_fusion_updates: bool = True
    status_period_s: float = 1.0
    map_to_odom_period_s: float = 0.1  # sensor time between map_to_odom messages (and after each VLoc fix)
    stage_join_timeout_s: float = 5.0  # shutdown: a stage not ending by then is reported
    stage_on_error: Literal["fail", "restart"] = "fail"
    stage_max_restarts: int = 3
    latency_window: int = 1024
    cv_threads: int = 2
    # ONNX Runtime intra-op threads of the service's models (overrides models.intra_op_threads
    # in `litevloc run/replay`). bench/runtime.py, simulated office, 2 CPUs, VLoc niced:
    # 1 thread: VLoc 2.2-2.4 Hz, fused-pose p99 3.0-4.9 ms in the service, 0.5-0.7 ms on the wire;
    # 2 threads: VLoc 3.0-3.3 Hz, p99 3.5-5.0 ms in the service but 2.4-3.1 ms on the wire (a
    # subscriber on the same 2 CPUs); without the nice, 2 threads gave p99 7.6 ms.
    ort_intra_op_threads: int = 1
    ort_inter_op_threads: int = 1
    # Linux nice value of the VLoc thread and of the onnxruntime threads its models start
    # (0 = normal priority): VLoc is throughput work, fusion and publishing are latency work.
    # With VLoc niced, the fusion thread gets a core the moment an odometry message arrives.
    vloc_nice: int = 10
    # 1-99: the fusion and publisher threads run SCHED_FIFO at this priority, so a fused pose never
    # waits for a core behind VLoc or I/O threads (bench/runtime.py, office, 2 CPUs: in-service p99
    # 6.1 -> 1.3 ms with publish_inline, defer_fusion_updates and recording_process); 0: normal. Needs
    # CAP_SYS_NICE or an rtprio limit (systemd LimitRTPRIO=); without, the threads keep normal
    # priority and the log and status (stages.fusion.scheduling) say why.
    fusion_rt_priority: int = 10
    # true: in realtime and deterministic mode the localizer (models, map) runs in a child process
    # at `vloc_nice` and the VLoc thread only waits on a pipe (runtime/vloc_process.py): VLoc's
    # Python glue never holds the service's GIL and a crash in it cannot take fusion down. Costs
    # ~80 MB RSS (a second interpreter); with fusion_rt_priority the p99 gain is small (2.7 -> 2.2
    # ms, one run), so off by default. The sequential baseline always runs VLoc inline.
    vloc_process: bool = False
    # true: a recording the service replays (`litevloc replay/run --source REC`, realtime and
    # deterministic mode) is read and decoded in a child process (runtime/recording_process.py):
    # the MCAP reader and CDR decoding of 200 Hz odometry otherwise hold the service's GIL.
    recording_process: bool = True
    # sys.setswitchinterval: how long a thread may hold the GIL while another waits. Python's
    # 5 ms default lets a GIL-holding VLoc step delay fused poses by 5-25 ms (measured, see
    # bench/runtime_queues.py); 0.5 ms keeps the fusion->publish p99 near 1-2 ms.
    gil_switch_interval_s: float = 0.0005
    # Tracking loss: LOST when no VLoc update was accepted for `lost_after_s` of sensor time
    # (after the first one). "flag": keep publishing, covariance diagonal raised to at least
    # `lost_variance` and status.state = LOST; "withhold": publish no pose/map_to_odom while LOST.
    lost_policy: Literal["flag", "withhold"] = "flag"
    lost_after_s: float = 10.0
    lost_variance: float = 1.0e4
    # Odometry input: from the sensor source (recordings, simulator) or received over Zenoh.
    odometry_input: Literal["source", "zenoh"] = "source"
    odometry_key: str = "odom"  # Zenoh key expression of the robot's nav_msgs/Odometry (not namespaced)
    odometry_stale_s: float = 0.5  # no odometry for this long (wall time) -> status reason
    frame_stale_s: float = 2.0  # no camera frame for this long (wall time, realtime mode) -> status reason
    odometry_checks: OdometryCheckParams = field(default_factory=OdometryCheckParams)
    deterministic_timeout_s: float = 120.0  # lockstep wait per frame before failing

    def __post_init__(self) -> None:
        for name in ("odometry_queue_capacity", "result_queue_capacity", "publish_queue_capacity",
                     "latency_window", "cv_threads", "ort_intra_op_threads", "ort_inter_op_threads"):
            if getattr(self, name) < 1:
                raise ValueError(f"runtime.{name} must be >= 1, got {getattr(self, name)}")
        if self.stage_max_restarts < 0:
            raise ValueError("runtime.stage_max_restarts must be >= 0")
        if not 0 <= self.fusion_rt_priority <= 99:
            raise ValueError(f"runtime.fusion_rt_priority must be in [0, 99], got {self.fusion_rt_priority}")
        if not 0 <= self.vloc_nice <= 19:
            raise ValueError(f"runtime.vloc_nice must be in [0, 19], got {self.vloc_nice}")
        if not (1e-5 <= self.gil_switch_interval_s <= 0.1):
            raise ValueError(f"runtime.gil_switch_interval_s must be in [1e-5, 0.1], got {self.gil_switch_interval_s}")
        for name in ("status_period_s", "map_to_odom_period_s", "stage_join_timeout_s", "lost_after_s",
                     "lost_variance", "odometry_stale_s", "frame_stale_s", "deterministic_timeout_s"):
            v = getattr(self, name)
            if not (v > 0 and v < float("inf")):
                raise ValueError(f"runtime.{name} must be a finite number > 0, got {v}")
        if not self.odometry_key or any(c in self.odometry_key for c in "$?#") or self.odometry_key.startswith("/"):
            raise ValueError(f"runtime.odometry_key {self.odometry_key!r} is not a valid key expression "
                             "(no leading '/', no $ ? #)")


# --------------------------------------------------------------------- planner (image-goal navigation)
# (appended for the navigation issue; used by litevloc.runtime.planner_service / `litevloc plan`)


@dataclass(frozen=True)
class PlannerConfig:
    """The planner service (`litevloc plan`): goal localization, subgoal tracking, publishing.

    Keys (namespaced like the runtime's): subscribes `litevloc/pose`, `litevloc/goal_image`,
    `litevloc/goal_cancel`; publishes `litevloc/subgoal`, `litevloc/subgoal_base`,
    `litevloc/planner_status`.
    """

    goal: GoalParams = field(default_factory=GoalParams)
    tracker: TrackerParams = field(default_factory=TrackerParams)
    # what `map build` / `map info` list as unmapped openings of a map's occupancy grid (where to go back)
    openings: OpeningParams = field(default_factory=OpeningParams)
    publish_period_s: float = 0.0  # sensor time between subgoal messages; 0 = on every fused pose
    status_period_s: float = 1.0  # wall time between repeated status messages
    max_queued_goals: int = 32
    max_goal_bytes: int = 8_000_000  # larger goal images are rejected (status failed)

    def __post_init__(self) -> None:
        if not (0 <= self.publish_period_s < float("inf")):
            raise ValueError(f"planner.publish_period_s must be finite and >= 0, got {self.publish_period_s}")
        if not (0 < self.status_period_s < float("inf")):
            raise ValueError(f"planner.status_period_s must be finite and > 0, got {self.status_period_s}")
        if self.max_queued_goals < 1 or self.max_goal_bytes < 1024:
            raise ValueError("planner.max_queued_goals must be >= 1 and planner.max_goal_bytes >= 1024")


# --------------------------------------------------------------------- diagnostics (issue 17)
# (used by litevloc.runtime.diagnostics: `litevloc/diagnostics`, diagnostic_msgs/DiagnosticArray)
@dataclass(frozen=True)
class LevelThresholds:
    """WARN at or above `warn`, ERROR at or above `error` (for "lower is worse" figures the
    diagnostics compare the other way: WARN at or below `warn`, ERROR at or below `error`)."""

    warn: float
    error: float


@dataclass(frozen=True)
class DiagnosticsConfig:
    """Levels of `litevloc/diagnostics` (one DiagnosticStatus per stage, queue, VLoc, tracking).

    Stage thresholds apply to the p99 execution time (ms) over the runtime's latency window:
    extract / vpr / match / pnp per VLoc query (match and pnp summed over the candidates of
    one query), fusion per odometry message, publish per published message. Queue depth is
    a fraction of capacity; any overflow (a never-drop FIFO refusing an item) is ERROR.
    VLoc rate (Hz) and acceptance (accepted / calls) are over the last diagnostics period
    and are "lower is worse"; they are only judged once `min_vloc_calls` calls were made.
    """

    enabled: bool = True
    period_s: float = 1.0  # wall time between DiagnosticArray messages (sent with the status tick)
    hardware_id: str = "litevloc"
    extract_ms: LevelThresholds = field(default_factory=lambda: LevelThresholds(500.0, 2000.0))
    vpr_ms: LevelThresholds = field(default_factory=lambda: LevelThresholds(300.0, 1000.0))
    match_ms: LevelThresholds = field(default_factory=lambda: LevelThresholds(1500.0, 5000.0))
    pnp_ms: LevelThresholds = field(default_factory=lambda: LevelThresholds(50.0, 200.0))
    fusion_ms: LevelThresholds = field(default_factory=lambda: LevelThresholds(10.0, 50.0))
    publish_ms: LevelThresholds = field(default_factory=lambda: LevelThresholds(10.0, 50.0))
    queue_fill: LevelThresholds = field(default_factory=lambda: LevelThresholds(0.5, 0.9))
    vloc_rate_hz: LevelThresholds = field(default_factory=lambda: LevelThresholds(0.5, 0.1))
    vloc_acceptance: LevelThresholds = field(default_factory=lambda: LevelThresholds(0.5, 0.1))
    min_vloc_calls: int = 3

    def __post_init__(self) -> None:
        if not (0 < self.period_s < float("inf")):
            raise ValueError(f"diagnostics.period_s must be finite and > 0, got {self.period_s}")
        if not self.hardware_id:
            raise ValueError("diagnostics.hardware_id must not be empty")
        if self.min_vloc_calls < 1:
            raise ValueError(f"diagnostics.min_vloc_calls must be >= 1, got {self.min_vloc_calls}")
        for name in ("extract_ms", "vpr_ms", "match_ms", "pnp_ms", "fusion_ms", "publish_ms", "queue_fill"):
            t = getattr(self, name)
            if not (0 <= t.warn <= t.error < float("inf")):
                raise ValueError(f"diagnostics.{name}: need 0 <= warn <= error (finite), got {t.warn}, {t.error}")
        for name in ("vloc_rate_hz", "vloc_acceptance"):
            t = getattr(self, name)
            if not (0 <= t.error <= t.warn < float("inf")):
                raise ValueError(f"diagnostics.{name} (lower is worse): need 0 <= error <= warn (finite), "
                                 f"got warn {t.warn}, error {t.error}")
