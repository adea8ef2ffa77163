"""The LiteVLoc configuration tree: typed, frozen dataclasses with their defaults.

With the parameter classes of `litevloc.base.params` it is the one place where defaults
live. YAML presets in `config/presets/` override them; `load_config` rejects unknown keys and
wrong types, naming the key and file.
Sections own the parameters of one subsystem; their parameter classes live in the bottom
layer `litevloc.base.params`, so importing the configuration imports no algorithm or hardware
module. Each field carries its description as the one `#` line above it
(`litevloc config show`, `docs/parameters.md`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from litevloc.base.frames import parse_frames
from litevloc.base.geometry import make_T, quat_xyzw_to_matrix
from litevloc.base.params.calibration import CalibrationParams, ColorDepthCalibration
from litevloc.base.params.camera import CameraConfig
from litevloc.base.params.depth import DepthOdometryParams, SgbmParams
from litevloc.base.params.drift import DriftParams
from litevloc.base.params.fusion import FusionParams
from litevloc.base.params.localization import LocalizationParams
from litevloc.base.params.mapping import MappingParams
from litevloc.base.params.models import ModelsConfig
from litevloc.base.params.navigation import GoalParams, OpeningParams, TrackerParams
from litevloc.base.params.odometry import OdometryCheckParams
from litevloc.base.params.sim import SimParams
from litevloc.base.params.sim_navigation import NavParams
from litevloc.base.params.slam import SlamParams


@dataclass(frozen=True)
class SourceConfig:
    """Where sensor data come from when no `--source` is given on the command line."""

    # what the sensor data come from: a kind of runtime/sources.py SOURCE_KINDS (recording, dataset, oak-d, sim)
    kind: str = "recording"
    # the recording or dataset folder ("" = none)
    path: str = ""
    # part of a recording or dataset: a Python slice over frame indices, as --frames
    frames: str = ""
    # true: fail on a bad message; false: count and skip it (live use)
    strict: bool = False

    def __post_init__(self) -> None:
        if self.kind in ("recording", "dataset") and self.frames:
            parse_frames(self.frames)


@dataclass(frozen=True)
class OdometrySimConfig:
    """Simulated proprioceptive odometry for posed datasets that have none."""

    # odometry rate written by `litevloc convert` (Hz; 0 = no odometry)
    rate_hz: float = 100.0
    # seed of the drift model
    seed: int = 0
    # the drift model's noise
    drift: DriftParams = field(default_factory=DriftParams)

    def __post_init__(self) -> None:
        if not (self.rate_hz >= 0 and self.rate_hz <= 2000):
            raise ValueError(f"rate_hz must be in [0, 2000], got {self.rate_hz}")


@dataclass(frozen=True)
class ReplayConfig:
    """Playback of recordings."""

    # real-time factor of a replay (0 = as fast as possible)
    rate: float = 1.0

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

    # the pose-graph fusion
    params: FusionParams = field(default_factory=FusionParams)
    # camera optical frame in base_link: translation (m)
    base_camera_translation: tuple[float, float, float] = (0.0, 0.0, 0.0)
    # camera optical frame in base_link: rotation (x, y, z, w); the default looks along base x
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

    # name of this configuration (shown in logs and status)
    name: str = "default"
    # map folder the service localizes in (`litevloc run` / `replay`; --map overrides)
    map: str = ""
    # where sensor data come from when no --source is given
    source: SourceConfig = field(default_factory=SourceConfig)
    # simulated odometry for posed datasets without any (`litevloc convert`)
    odometry_sim: OdometrySimConfig = field(default_factory=OdometrySimConfig)
    # playback of recordings
    replay: ReplayConfig = field(default_factory=ReplayConfig)
    # the live OAK-D camera (source.kind: oak-d)
    camera: CameraConfig = field(default_factory=CameraConfig)
    # the models and how onnxruntime runs them
    models: ModelsConfig = field(default_factory=ModelsConfig)
    # map building, merging, updating and comparing
    mapping: MappingParams = field(default_factory=MappingParams)
    # the mapping pass's own SLAM (`litevloc map build --poses slam`)
    slam: SlamParams = field(default_factory=SlamParams)
    # GL/LL localization against the map
    localization: LocalizationParams = field(default_factory=LocalizationParams)
    # pose-graph fusion of VLoc and odometry, and the camera mount
    fusion: FusionConfig = field(default_factory=FusionConfig)
    # the simulated robot and camera
    sim: SimParams = field(default_factory=SimParams)
    # closed-loop navigation in the simulator (`litevloc sim navigate`, demo): rates, local planner, search
    sim_navigation: NavParams = field(default_factory=NavParams)
    # the Zenoh session
    zenoh: ZenohConfig = field(default_factory=lambda: ZenohConfig())
    # threads, queues, status and tracking-loss policy of the onboard service
    runtime: RuntimeConfig = field(default_factory=lambda: RuntimeConfig())
    # colour camera of an RGB-D dataset whose depth is not registered (7-Scenes); null = as published
    rgbd_calibration: ColorDepthCalibration | None = None
    # the planner service (goal images -> subgoals)
    planner: PlannerConfig = field(default_factory=lambda: PlannerConfig())
    # levels of the `litevloc/diagnostics` messages
    diagnostics: DiagnosticsConfig = field(default_factory=lambda: DiagnosticsConfig())
    # `litevloc calib`: colour camera of an RGB-D dataset from posed frames
    calibration: CalibrationParams = field(default_factory=CalibrationParams)
    # depth from a stereo pair (`pipelines.stereo_depth`, `bench/stereo.py`)
    stereo: SgbmParams = field(default_factory=SgbmParams)
    # frame-to-frame RGB-D odometry (`pipelines.depth_odometry`, `bench/depth_odometry.py`)
    depth_odometry: DepthOdometryParams = field(default_factory=DepthOdometryParams)


# --------------------------------------------------------------------- runtime / Zenoh
# (used by litevloc.runtime.transport.bus / service)
_ENDPOINT_PROTOCOLS = ("tcp", "udp", "tls", "quic", "unixsock-stream", "ws", "serial")


def _check_endpoint(ep: str, where: str) -> None:
    proto, sep, rest = ep.partition("/")
    if not sep or proto not in _ENDPOINT_PROTOCOLS or not rest:
        raise ValueError(
            f"{where} endpoint {ep!r} must look like tcp/127.0.0.1:7447 (protocol one of {list(_ENDPOINT_PROTOCOLS)})"
        )


@dataclass(frozen=True)
class TfConfig:
    """ROS frames and the `/tf` / `/tf_static` output (REP-105: `map -> odom` is the localizer's)."""

    # frame_id of every map-frame message (poses, VLoc fixes, subgoals, the parent of map -> odom)
    map_frame: str = "map"
    # the robot's odometry frame: child of map -> odom on /tf, parent of its nav_msgs/Odometry input
    odom_frame: str = "odom"
    # the robot body frame the camera extrinsics (fusion.base_camera_*) refer to
    base_frame: str = "base_link"
    # map -> odom on /tf (tf2_msgs/TFMessage) with every litevloc/map_to_odom message
    publish_tf: bool = True
    # seconds added to the map -> odom stamp, as AMCL's transform_tolerance (0 = the odometry's stamp)
    post_date_s: float = 0.0
    # camera optical frame: "" = no /tf_static; else base -> camera (fusion.base_camera_*) on /tf_static
    camera_frame: str = ""

    def __post_init__(self) -> None:
        for name in ("map_frame", "odom_frame", "base_frame"):
            v = getattr(self, name)
            if not v or v.startswith("/") or any(c.isspace() for c in v):
                raise ValueError(f"zenoh.tf.{name} {v!r} must be a non-empty frame id without '/' prefix or spaces")
        frames = [self.map_frame, self.odom_frame, self.base_frame] + ([self.camera_frame] if self.camera_frame else [])
        if len(set(frames)) != len(frames):
            raise ValueError(f"zenoh.tf frame ids must differ from each other, got {frames}")
        if not (0.0 <= self.post_date_s <= 10.0):
            raise ValueError(f"zenoh.tf.post_date_s must be in [0, 10] s, got {self.post_date_s}")


@dataclass(frozen=True)
class InitialPoseConfig:
    """`/initialpose` (geometry_msgs/PoseWithCovarianceStamped, RViz's "2D Pose Estimate"): a prior
    that bounds the next global localization to map keyframes near it."""

    # true: subscribe to `initialpose` (in the node's namespace)
    enabled: bool = True
    # search radius = max(min_radius_m, sigmas x the larger x/y standard deviation of the covariance), metres
    sigmas: float = 3.0
    # smallest search radius (metres): RViz sends a 0.5 m standard deviation; a zero covariance gets this
    min_radius_m: float = 2.0
    # an x or y standard deviation above this (metres) is refused: it would bound nothing
    max_sigma_m: float = 50.0
    # seconds of sensor time the bound holds while no VLoc fix is accepted near it; then GL searches the whole map
    hold_s: float = 30.0

    def __post_init__(self) -> None:
        if not (0 < self.sigmas <= 10 and 0 < self.min_radius_m <= 1000 and 0 < self.max_sigma_m <= 1e4
                and 0 < self.hold_s <= 3600):
            raise ValueError("zenoh.initial_pose: need 0 < sigmas <= 10, 0 < min_radius_m <= 1000, "
                             "0 < max_sigma_m <= 1e4, 0 < hold_s <= 3600")


@dataclass(frozen=True)
class ZenohConfig:
    """The Zenoh session: always explicit (Zenoh's own default listens on every interface
    and multicasts; ours listens on loopback only and does not scout).

    `tls`, `access_control` and `extra` are passed through to Zenoh's JSON5 config:
    `tls` goes to `transport/link/tls` (a mapping, or JSON5 text), `access_control` to
    `access_control`, and `extra` is a mapping {zenoh config key path: value} inserted
    last (e.g. {"transport/shared_memory/enabled": false}). See the Zenoh config reference.
    """

    # Zenoh mode: peer (listens) or client (connects to a router)
    mode: Literal["peer", "client"] = "peer"
    # endpoints to listen on (ignored in client mode)
    listen: tuple[str, ...] = ("tcp/127.0.0.1:7447",)
    # endpoints to connect to
    connect: tuple[str, ...] = ()
    # multicast scouting (off: peers are found through listen/connect only)
    multicast_scouting: bool = False
    # wait per connect attempt at start-up (s)
    connect_timeout_s: float = 3.0
    # start fails if no connect endpoint is reachable
    require_connect: bool = True
    # key prefix, e.g. "robot1" -> robot1/litevloc/pose; with rmw_zenoh the ROS namespace of every node and topic
    namespace: str = ""
    # key naming: "bridge" (zenoh-bridge-ros2dds keys) or "rmw_zenoh" (ROS 2's own Zenoh middleware, docs/ros2.md)
    ros2: Literal["bridge", "rmw_zenoh"] = "bridge"
    # rmw_zenoh only: the robot's ROS 2, "jazzy" (Ubuntu 24.04) or "humble" (22.04, JetPack 6); "auto" reads ROS_DISTRO
    ros2_distro: Literal["jazzy", "humble", "auto"] = "jazzy"
    # ROS_DOMAIN_ID of the robot (rmw_zenoh only; 0-232 as in ROS 2)
    domain_id: int = 0
    # ROS node name of the runtime (rmw_zenoh liveliness); the planner is `<node_name>_planner`
    node_name: str = "litevloc"
    # frames, /tf and /tf_static
    tf: TfConfig = field(default_factory=TfConfig)
    # the /initialpose input
    initial_pose: InitialPoseConfig = field(default_factory=InitialPoseConfig)
    # planner goals for Nav2 on goal_pose (frame map): each "subgoal", the "goal" image's place once, or "off"
    goal_pose: Literal["off", "subgoal", "goal"] = "off"
    # 8-byte little-endian monotonic send time (ns) as the Zenoh attachment of every message
    attach_send_time: bool = True
    # Zenoh's transport/link/tls block (a mapping or JSON5 text)
    tls: Any = None
    # Zenoh's access_control block (a mapping or JSON5 text)
    access_control: Any = None
    # {Zenoh config key path: value} inserted last, e.g. {"transport/shared_memory/enabled": false}
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
        if not 0 <= self.domain_id <= 232:
            raise ValueError(f"zenoh.domain_id must be in [0, 232] (ROS_DOMAIN_ID), got {self.domain_id}")
        if not self.node_name or not all(c.isalnum() or c == "_" for c in self.node_name) or \
                self.node_name[0].isdigit():
            raise ValueError(f"zenoh.node_name {self.node_name!r} is not a ROS node name (letters, digits, '_', "
                             "not starting with a digit)")
        if self.ros2 == "rmw_zenoh" and ns and not all(c.isalnum() or c in "_/" for c in ns):
            raise ValueError(f"zenoh.namespace {ns!r} is not a ROS namespace (letters, digits, '_', '/')")


@dataclass(frozen=True)
class RuntimeConfig:
    """Threads, queues, status and tracking-loss policy of the onboard service."""

    # realtime: threads, latest frame only; deterministic: lockstep, every frame; sequential: one thread
    mode: Literal["realtime", "deterministic", "sequential"] = "realtime"
    # odometry FIFO capacity (messages; never drops, overflow is counted)
    odometry_queue_capacity: int = 4096
    # VLoc result FIFO capacity (results)
    result_queue_capacity: int = 64
    # realtime: before a frame's VLoc, wait at most this long for fusion to take the previous result (ms; 0 = no wait)
    prior_wait_ms: float = 100.0
    # outbox FIFO capacity (messages)
    publish_queue_capacity: int = 4096
    # the fusion thread serialises and puts on Zenoh itself (false: through the outbox to a publisher thread)
    publish_inline: bool = True
    # the smoother update that a fusion keyframe makes due runs after the pose is handed on
    defer_fusion_updates: bool = True
    # wall time between status messages (s)
    status_period_s: float = 1.0
    # sensor time between map_to_odom messages, and after each VLoc fix (s)
    map_to_odom_period_s: float = 0.1
    # shutdown: a stage not ending within this is reported (s)
    stage_join_timeout_s: float = 5.0
    # what a failing stage does: stop the service, or restart the stage
    stage_on_error: Literal["fail", "restart"] = "fail"
    # restarts of one stage at most
    stage_max_restarts: int = 3
    # samples per stage in the latency window (status percentiles)
    latency_window: int = 1024
    # OpenCV threads
    cv_threads: int = 2
    # onnxruntime intra-op threads of the service's models (run/replay/plan; models.intra_op_threads elsewhere)
    ort_intra_op_threads: int = 1
    # onnxruntime inter-op threads of the service's models
    ort_inter_op_threads: int = 1
    # Linux nice value of the VLoc thread and its onnxruntime threads (0 = normal priority)
    vloc_nice: int = 10
    # SCHED_FIFO priority of the fusion and publisher threads (1-99; 0 = normal; needs CAP_SYS_NICE or rtprio)
    fusion_rt_priority: int = 10
    # run the localizer (models, map) in a child process at vloc_nice (realtime/deterministic mode)
    vloc_process: bool = False
    # read and decode a replayed recording in a child process (realtime/deterministic mode)
    recording_process: bool = True
    # sys.setswitchinterval: how long a thread may hold the GIL while another waits (s)
    gil_switch_interval_s: float = 0.0005
    # while LOST: "flag" publishes with the covariance raised, "withhold" publishes no pose
    lost_policy: Literal["flag", "withhold"] = "flag"
    # LOST when no VLoc update was accepted for this much sensor time after the first (s)
    lost_after_s: float = 10.0
    # "flag": the covariance diagonal is raised to at least this while LOST (m^2, rad^2)
    lost_variance: float = 1.0e4
    # odometry from the sensor source (recordings, simulator) or received over Zenoh
    odometry_input: Literal["source", "zenoh"] = "source"
    # Zenoh key expression of the robot's nav_msgs/Odometry (not namespaced)
    odometry_key: str = "odom"
    # no odometry for this long (wall time) is a status reason (s)
    odometry_stale_s: float = 0.5
    # no camera frame for this long (wall time, realtime mode) is a status reason (s)
    frame_stale_s: float = 2.0
    # checks and frame handling of received odometry
    odometry_checks: OdometryCheckParams = field(default_factory=OdometryCheckParams)
    # deterministic mode: lockstep wait per frame before failing (s)
    deterministic_timeout_s: float = 120.0

    def __post_init__(self) -> None:
        for name in ("odometry_queue_capacity", "result_queue_capacity", "publish_queue_capacity",
                     "latency_window", "cv_threads", "ort_intra_op_threads", "ort_inter_op_threads"):
            if getattr(self, name) < 1:
                raise ValueError(f"runtime.{name} must be >= 1, got {getattr(self, name)}")
        if self.stage_max_restarts < 0:
            raise ValueError("runtime.stage_max_restarts must be >= 0")
        if not (math.isfinite(self.prior_wait_ms) and self.prior_wait_ms >= 0):
            raise ValueError(f"runtime.prior_wait_ms must be a finite number >= 0, got {self.prior_wait_ms}")
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
# (used by litevloc.runtime.planner.node / `litevloc plan`)


@dataclass(frozen=True)
class PlannerConfig:
    """The planner service (`litevloc plan`): goal localization, subgoal tracking, publishing.

    Keys (namespaced like the runtime's): subscribes `litevloc/pose`, `litevloc/goal_image`,
    `litevloc/goal_cancel`; publishes `litevloc/subgoal`, `litevloc/subgoal_base`,
    `litevloc/planner_status`.
    """

    # placing a goal image in the map
    goal: GoalParams = field(default_factory=GoalParams)
    # following the planned path
    tracker: TrackerParams = field(default_factory=TrackerParams)
    # what `map build` / `map info` list as unmapped openings of a map's occupancy grid (where to go back)
    openings: OpeningParams = field(default_factory=OpeningParams)
    # sensor time between subgoal messages (s; 0 = on every fused pose)
    publish_period_s: float = 0.0
    # wall time between repeated status messages (s)
    status_period_s: float = 1.0
    # goal images queued at most
    max_queued_goals: int = 32
    # larger goal images are rejected (bytes)
    max_goal_bytes: int = 8_000_000

    def __post_init__(self) -> None:
        if not (0 <= self.publish_period_s < float("inf")):
            raise ValueError(f"planner.publish_period_s must be finite and >= 0, got {self.publish_period_s}")
        if not (0 < self.status_period_s < float("inf")):
            raise ValueError(f"planner.status_period_s must be finite and > 0, got {self.status_period_s}")
        if self.max_queued_goals < 1 or self.max_goal_bytes < 1024:
            raise ValueError("planner.max_queued_goals must be >= 1 and planner.max_goal_bytes >= 1024")


# --------------------------------------------------------------------- diagnostics
# (used by litevloc.runtime.service.diagnostics: `litevloc/diagnostics`, diagnostic_msgs/DiagnosticArray)
@dataclass(frozen=True)
class LevelThresholds:
    """WARN at or above `warn`, ERROR at or above `error` (for "lower is worse" figures the
    diagnostics compare the other way: WARN at or below `warn`, ERROR at or below `error`)."""

    # WARN at or beyond this
    warn: float
    # ERROR at or beyond this
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

    # publish `litevloc/diagnostics`
    enabled: bool = True
    # wall time between DiagnosticArray messages, sent with the status tick (s)
    period_s: float = 1.0
    # hardware_id of every DiagnosticStatus
    hardware_id: str = "litevloc"
    # p99 of feature extraction per VLoc query (ms)
    extract_ms: LevelThresholds = field(default_factory=lambda: LevelThresholds(500.0, 2000.0))
    # p99 of place recognition per VLoc query (ms)
    vpr_ms: LevelThresholds = field(default_factory=lambda: LevelThresholds(300.0, 1000.0))
    # p99 of matching per VLoc query, candidates summed (ms)
    match_ms: LevelThresholds = field(default_factory=lambda: LevelThresholds(1500.0, 5000.0))
    # p99 of PnP per VLoc query, candidates summed (ms)
    pnp_ms: LevelThresholds = field(default_factory=lambda: LevelThresholds(50.0, 200.0))
    # p99 of fusion per odometry message (ms)
    fusion_ms: LevelThresholds = field(default_factory=lambda: LevelThresholds(10.0, 50.0))
    # p99 of publishing per message (ms)
    publish_ms: LevelThresholds = field(default_factory=lambda: LevelThresholds(10.0, 50.0))
    # queue depth as a fraction of its capacity
    queue_fill: LevelThresholds = field(default_factory=lambda: LevelThresholds(0.5, 0.9))
    # VLoc rate over the last period (Hz; lower is worse)
    vloc_rate_hz: LevelThresholds = field(default_factory=lambda: LevelThresholds(0.5, 0.1))
    # accepted / calls over the last period (lower is worse)
    vloc_acceptance: LevelThresholds = field(default_factory=lambda: LevelThresholds(0.5, 0.1))
    # VLoc rate and acceptance are judged only after this many calls
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
