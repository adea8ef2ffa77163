"""The LiteVLoc configuration tree: typed, frozen dataclasses with their defaults.

With the parameter classes of `litevloc.base.params` it is the one place where defaults
live. YAML presets in `config/presets/` override them; `load_config` rejects unknown keys and
wrong types, naming the key and file.
Sections own the parameters of one subsystem; their parameter classes live in the bottom
layer `litevloc.base.params`, so importing the configuration imports no algorithm or hardware
module. Each field is declared once with `litevloc.base.settings.setting` (default, description,
unit, range), which `litevloc config show` and `docs/parameters.md` print.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from litevloc.base.frames import parse_frames
from litevloc.base.geometry import make_T, quat_xyzw_to_matrix
from litevloc.base.params.calibration import CalibrationParams, ColorDepthCalibration
from litevloc.base.params.camera import CameraConfig
from litevloc.base.params.depth import DepthOdometryParams, SgbmParams
from litevloc.base.params.drift import DriftParams
from litevloc.base.params.fleet import FleetParams
from litevloc.base.params.fusion import FusionParams
from litevloc.base.params.localization import LocalizationParams
from litevloc.base.params.mapping import MappingParams
from litevloc.base.params.models import ModelsConfig
from litevloc.base.params.navigation import GoalParams, OpeningParams, TrackerParams
from litevloc.base.params.odometry import OdometryCheckParams
from litevloc.base.params.sim import SimParams
from litevloc.base.params.sim_navigation import NavParams
from litevloc.base.params.slam import SlamParams
from litevloc.base.settings import Settings, section, setting


@dataclass(frozen=True)
class SourceConfig(Settings):
    """Where sensor data come from when no `--source` is given on the command line."""

    kind: str = setting("recording", "what the sensor data come from: a kind registered in "
                        "runtime/sources.py SOURCE_KINDS (recording, dataset, oak-d, sim)")
    path: str = setting("", "the recording or dataset folder ('' = none)")
    frames: str = setting("", "part of a recording or dataset: a Python slice over frame indices, as --frames")
    strict: bool = setting(False, "true: fail on a bad message; false: count and skip it (live use)")

    def check_relations(self) -> None:
        if self.kind in ("recording", "dataset") and self.frames:
            parse_frames(self.frames)


@dataclass(frozen=True)
class OdometrySimConfig(Settings):
    """Simulated proprioceptive odometry for posed datasets that have none."""

    rate_hz: float = setting(
        100.0, "odometry rate written by `litevloc convert` (0 = no odometry)", unit="Hz", low=0, high=2000)
    seed: int = setting(0, "seed of the simulated odometry's drift model", low=-math.inf)
    drift: DriftParams = section(DriftParams, "the drift model's noise")


@dataclass(frozen=True)
class ReplayConfig(Settings):
    """Playback of recordings."""

    rate: float = setting(1.0, "real-time factor of a replay (0 = as fast as possible)", low=0)


@dataclass(frozen=True)
class FusionConfig(Settings):
    """Pose SLAM (VLoc + odometry fusion) and the camera extrinsics it needs.

    `base_camera_*`: pose of the camera optical frame in base_link (`T_base_camera`);
    the default is a camera at the base origin looking along base x (REP-103 body axes),
    as used for datasets where base_link is the camera.
    """

    params: FusionParams = section(FusionParams, "the pose-graph fusion")
    base_camera_translation: tuple[float, float, float] = setting(
        (0.0, 0.0, 0.0), "camera optical frame in base_link: translation", unit="m", low=-math.inf)
    base_camera_quat_xyzw: tuple[float, float, float, float] = setting(
        (-0.5, 0.5, -0.5, 0.5),
        "camera optical frame in base_link: rotation (x, y, z, w); the default looks along base x", low=-math.inf)

    def check_relations(self) -> None:
        n = math.sqrt(sum(v * v for v in self.base_camera_quat_xyzw))
        if abs(n - 1.0) > 1e-3:
            raise ValueError(f"base_camera_quat_xyzw must be a unit quaternion (x, y, z, w), norm is {n:.6f}")

    def T_base_camera(self) -> NDArray[np.float64]:
        """4x4 float64 T_base_camera from the configured translation and quaternion."""
        q, t = np.asarray(self.base_camera_quat_xyzw), np.asarray(self.base_camera_translation)
        return make_T(quat_xyzw_to_matrix(q), t)


@dataclass(frozen=True)
class LiteVLocConfig(Settings):
    """Root of the configuration tree."""

    name: str = setting("default", "name of this configuration (shown in logs and status)")
    map: str = setting("", "map folder the service localizes in (`litevloc run` / `replay`; --map overrides)")
    source: SourceConfig = section(SourceConfig, "where sensor data come from when no --source is given")
    odometry_sim: OdometrySimConfig = section(
        OdometrySimConfig, "simulated odometry for posed datasets without any (`litevloc convert`)")
    replay: ReplayConfig = section(ReplayConfig, "playback of recordings")
    camera: CameraConfig = section(CameraConfig, "the live OAK-D camera (source.kind: oak-d)")
    models: ModelsConfig = section(ModelsConfig, "the models and how onnxruntime runs them")
    mapping: MappingParams = section(MappingParams, "map building, merging, updating and comparing")
    slam: SlamParams = section(SlamParams, "the mapping pass's own SLAM (`litevloc map build --poses slam`)")
    localization: LocalizationParams = section(LocalizationParams, "GL/LL localization against the map")
    fusion: FusionConfig = section(FusionConfig, "pose-graph fusion of VLoc and odometry, and the camera mount")
    sim: SimParams = section(SimParams, "the simulated robot and camera")
    sim_navigation: NavParams = section(
        NavParams, "closed-loop navigation in the simulator (`litevloc sim navigate`, demo): rates, local planner, "
        "search")
    zenoh: ZenohConfig = section(lambda: ZenohConfig(), "the Zenoh session")
    runtime: RuntimeConfig = section(
        lambda: RuntimeConfig(), "threads, queues, status and tracking-loss policy of the onboard service")
    rgbd_calibration: ColorDepthCalibration | None = setting(
        None, "colour camera of an RGB-D dataset whose depth is not registered (7-Scenes); null = as published")
    planner: PlannerConfig = section(lambda: PlannerConfig(), "the planner service (goal images -> subgoals)")
    diagnostics: DiagnosticsConfig = section(
        lambda: DiagnosticsConfig(), "levels of the `litevloc/diagnostics` messages")
    calibration: CalibrationParams = section(
        CalibrationParams, "`litevloc calib`: colour camera of an RGB-D dataset from posed frames")
    stereo: SgbmParams = section(SgbmParams, "depth from a stereo pair (`pipelines.stereo_depth`, `bench/stereo.py`)")
    depth_odometry: DepthOdometryParams = section(
        DepthOdometryParams, "frame-to-frame RGB-D odometry (`pipelines.depth_odometry`, `bench/depth_odometry.py`)")
    fleet: FleetParams = section(
        FleetParams, "the map service and the robots' map fetch (`litevloc map serve|fetch|push`, `run --map "
        "zenoh:NAME`)")


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
class TfConfig(Settings):
    """ROS frames and the `/tf` / `/tf_static` output (REP-105: `map -> odom` is the localizer's)."""

    map_frame: str = setting(
        "map", "frame_id of every map-frame message (poses, VLoc fixes, subgoals, the parent of map -> odom)")
    odom_frame: str = setting(
        "odom", "the robot's odometry frame: child of map -> odom on /tf, parent of its nav_msgs/Odometry input")
    base_frame: str = setting("base_link", "the robot body frame the camera extrinsics (fusion.base_camera_*) refer to")
    publish_tf: bool = setting(True, "map -> odom on /tf (tf2_msgs/TFMessage) with every litevloc/map_to_odom message")
    post_date_s: float = setting(
        0.0, "time added to the map -> odom stamp, as AMCL's transform_tolerance (0 = the odometry's stamp)", low=0,
        high=10, unit="s")
    camera_frame: str = setting(
        "", "camera optical frame: \"\" = no /tf_static; else base -> camera (fusion.base_camera_*) on /tf_static")

    def check_relations(self) -> None:
        for name in ("map_frame", "odom_frame", "base_frame"):
            v = getattr(self, name)
            if not v or v.startswith("/") or any(c.isspace() for c in v):
                raise ValueError(f"zenoh.tf.{name} {v!r} must be a non-empty frame id without '/' prefix or spaces")
        frames = [self.map_frame, self.odom_frame, self.base_frame] + ([self.camera_frame] if self.camera_frame else [])
        if len(set(frames)) != len(frames):
            raise ValueError(f"zenoh.tf frame ids must differ from each other, got {frames}")


@dataclass(frozen=True)
class InitialPoseConfig(Settings):
    """`/initialpose` (geometry_msgs/PoseWithCovarianceStamped, RViz's "2D Pose Estimate"): a prior
    that bounds the next global localization to map keyframes near it."""

    enabled: bool = setting(True, "true: subscribe to `initialpose` (in the node's namespace)")
    sigmas: float = setting(
        3.0, "search radius = max(min_radius_m, sigmas x the larger x/y standard deviation of the covariance)", low=0,
        low_open=True, high=10)
    min_radius_m: float = setting(
        2.0, "smallest search radius: RViz sends a 0.5 m standard deviation; a zero covariance gets this", unit="m",
        low=0, low_open=True, high=1000)
    max_sigma_m: float = setting(
        50.0, "an x or y standard deviation above this is refused: it would bound nothing", unit="m", low=0,
        low_open=True, high=1e4)
    hold_s: float = setting(
        30.0, "sensor time the bound holds while no VLoc fix is accepted near it; then GL searches the whole map",
        unit="s", low=0, low_open=True, high=3600)


@dataclass(frozen=True)
class ZenohConfig(Settings):
    """The Zenoh session: always explicit (Zenoh's own default listens on every interface
    and multicasts; ours listens on loopback only and does not scout).

    `tls`, `access_control` and `extra` are passed through to Zenoh's JSON5 config:
    `tls` goes to `transport/link/tls` (a mapping, or JSON5 text), `access_control` to
    `access_control`, and `extra` is a mapping {zenoh config key path: value} inserted
    last (e.g. {"transport/shared_memory/enabled": false}). See the Zenoh config reference.
    """

    mode: Literal["peer", "client"] = setting("peer", "Zenoh mode: peer (listens) or client (connects to a router)")
    listen: tuple[str, ...] = setting(("tcp/127.0.0.1:7447",), "endpoints to listen on (ignored in client mode)")
    connect: tuple[str, ...] = setting((), "endpoints to connect to")
    multicast_scouting: bool = setting(False, "multicast scouting (off: peers are found through listen/connect only)")
    connect_timeout_s: float = setting(
        3.0, "wait per connect attempt at start-up", unit="s", low=0, low_open=True, high=600)
    require_connect: bool = setting(True, "start fails if no connect endpoint is reachable")
    namespace: str = setting(
        "", 'key prefix, e.g. "robot1" -> robot1/litevloc/pose; with rmw_zenoh the ROS namespace of every node and '
        "topic")
    ros2: Literal["bridge", "rmw_zenoh"] = setting(
        "bridge", "key naming: \"bridge\" (zenoh-bridge-ros2dds keys) or \"rmw_zenoh\" (ROS 2's own Zenoh middleware, "
        "docs/ros2.md)")
    ros2_distro: Literal["jazzy", "humble", "auto"] = setting(
        "jazzy", "rmw_zenoh only: the robot's ROS 2, \"jazzy\" (Ubuntu 24.04) or \"humble\" (22.04, JetPack 6); "
        '"auto" reads ROS_DISTRO')
    domain_id: int = setting(0, "ROS_DOMAIN_ID of the robot (rmw_zenoh only, as in ROS 2)", low=0, high=232)
    node_name: str = setting(
        "litevloc", "ROS node name of the runtime (rmw_zenoh liveliness); the planner is `<node_name>_planner`")
    tf: TfConfig = section(TfConfig, "frames, /tf and /tf_static")
    initial_pose: InitialPoseConfig = section(InitialPoseConfig, "the /initialpose input")
    goal_pose: Literal["off", "subgoal", "goal"] = setting(
        "off", "planner goals for Nav2 on goal_pose (frame map): each \"subgoal\", the \"goal\" image's place once, "
        'or "off"')
    attach_send_time: bool = setting(
        True, "8-byte little-endian monotonic send time (ns) as the Zenoh attachment of every message")
    tls: Any = setting(None, "Zenoh's transport/link/tls block (a mapping or JSON5 text)")
    access_control: Any = setting(None, "Zenoh's access_control block (a mapping or JSON5 text)")
    extra: Any = setting(
        None, "{Zenoh config key path: value} inserted last, e.g. {\"transport/shared_memory/enabled\": false}")

    def check_relations(self) -> None:
        for ep in self.listen:
            _check_endpoint(ep, "zenoh.listen")
        for ep in self.connect:
            _check_endpoint(ep, "zenoh.connect")
        if self.mode == "client" and not self.connect:
            raise ValueError("zenoh.mode 'client' needs at least one zenoh.connect endpoint (a router)")
        ns = self.namespace
        if ns and (ns.startswith("/") or ns.endswith("/") or any(c in ns for c in "*$?#")):
            raise ValueError(f"zenoh.namespace {ns!r} must not start/end with '/' nor contain * $ ? #")
        for name in ("tls", "access_control", "extra"):
            v = getattr(self, name)
            if v is not None and not isinstance(v, str | dict):
                raise ValueError(f"zenoh.{name} must be a mapping or JSON5 text, got {type(v).__name__}")
        if self.extra is not None and not isinstance(self.extra, dict):
            raise ValueError("zenoh.extra must be a mapping {config key path: value}")
        if not self.node_name or not all(c.isalnum() or c == "_" for c in self.node_name) or \
                self.node_name[0].isdigit():
            raise ValueError(f"zenoh.node_name {self.node_name!r} is not a ROS node name (letters, digits, '_', "
                             "not starting with a digit)")
        if self.ros2 == "rmw_zenoh" and ns and not all(c.isalnum() or c in "_/" for c in ns):
            raise ValueError(f"zenoh.namespace {ns!r} is not a ROS namespace (letters, digits, '_', '/')")


@dataclass(frozen=True)
class MapSwitchConfig(Settings):
    """Switching to a new version of the map while running (`runtime.service.map_switch`): the
    version is refused when the keyframes both versions hold disagree (another map frame)."""

    frame_tolerance_m: float = setting(
        0.10, "largest median position difference of the keyframes both versions hold", unit="m", low=0,
        low_open=True)
    frame_tolerance_deg: float = setting(
        2.0, "largest median rotation difference of the keyframes both versions hold", unit="deg", low=0,
        low_open=True)


@dataclass(frozen=True)
class RuntimeConfig(Settings):
    """Threads, queues, status and tracking-loss policy of the onboard service."""

    mode: Literal["realtime", "deterministic", "sequential"] = setting(
        "realtime", "realtime: threads, latest frame only; deterministic: lockstep, every frame; sequential: one "
        "thread")
    odometry_queue_capacity: int = setting(
        4096, "odometry FIFO capacity (messages; never drops, overflow is counted)", low=1)
    result_queue_capacity: int = setting(64, "VLoc result FIFO capacity (results)", low=1)
    prior_wait_ms: float = setting(
        100.0,
        "realtime: before a frame's VLoc, wait at most this long for fusion to take the previous result (0 = no wait)",
        unit="ms", low=0)
    publish_queue_capacity: int = setting(4096, "outbox FIFO capacity (messages)", low=1)
    publish_inline: bool = setting(
        True, "the fusion thread serialises and puts on Zenoh itself (false: through the outbox to a publisher thread)")
    defer_fusion_updates: bool = setting(
        True, "the smoother update that a fusion keyframe makes due runs after the pose is handed on")
    status_period_s: float = setting(1.0, "wall time between status messages", unit="s", low=0, low_open=True)
    map_to_odom_period_s: float = setting(
        0.1, "sensor time between map_to_odom messages, and after each VLoc fix", unit="s", low=0, low_open=True)
    stage_join_timeout_s: float = setting(
        5.0, "at shutdown, a stage not ending within this is reported", unit="s", low=0, low_open=True)
    stage_on_error: Literal["fail", "restart"] = setting(
        "fail", "what a failing stage does: stop the service, or restart the stage")
    stage_max_restarts: int = setting(3, "restarts of one stage at most (stage_on_error: restart)", low=0)
    latency_window: int = setting(1024, "samples per stage in the latency window (status percentiles)", low=1)
    cv_threads: int = setting(2, "OpenCV threads of the onboard service", low=1)
    ort_intra_op_threads: int = setting(
        2, "onnxruntime intra-op threads of the service's models (run/replay/plan; models.intra_op_threads elsewhere)",
        low=1)
    ort_inter_op_threads: int = setting(1, "onnxruntime inter-op threads of the service's models", low=1)
    vloc_nice: int = setting(
        10, "Linux nice value of the VLoc thread and its onnxruntime threads (0 = normal priority)", low=0, high=19)
    fusion_rt_priority: int = setting(
        10, "SCHED_FIFO priority of the fusion and publisher threads (1-99; 0 = normal; needs CAP_SYS_NICE or rtprio)",
        low=0, high=99)
    transport_rt_priority: int = setting(
        10, "SCHED_FIFO priority of the service's Zenoh I/O threads, which put every fused pose on the wire "
        "(1-99; 0 = normal; needs CAP_SYS_NICE or rtprio, else normal priority and a warning)", low=0, high=99)
    vloc_process: bool = setting(
        False, "run the localizer (models, map) in a child process at vloc_nice (realtime/deterministic mode)")
    recording_process: bool = setting(
        True, "read and decode a replayed recording in a child process (realtime/deterministic mode)")
    gil_switch_interval_s: float = setting(
        0.0005, "sys.setswitchinterval: how long a thread may hold the GIL while another waits", unit="s", low=1e-5,
        high=0.1)
    lost_policy: Literal["flag", "withhold"] = setting(
        "flag", "while LOST: \"flag\" publishes with the covariance raised, \"withhold\" publishes no pose")
    lost_after_s: float = setting(
        10.0, "LOST when no VLoc update was accepted for this much sensor time after the first", unit="s", low=0,
        low_open=True)
    lost_variance: float = setting(
        1.0e4, "with lost_policy 'flag', the covariance diagonal is raised to at least this while LOST",
        unit="m^2, rad^2", low=0, low_open=True)
    odometry_input: Literal["source", "zenoh"] = setting(
        "source", "odometry from the sensor source (recordings, simulator) or received over Zenoh")
    odometry_key: str = setting("odom", "Zenoh key expression of the robot's nav_msgs/Odometry (not namespaced)")
    odometry_stale_s: float = setting(
        0.5, "no odometry for this long (wall time) is a status reason", unit="s", low=0, low_open=True)
    frame_stale_s: float = setting(
        2.0, "no camera frame for this long (wall time, realtime mode) is a status reason", unit="s", low=0,
        low_open=True)
    odometry_checks: OdometryCheckParams = section(
        OdometryCheckParams, "checks and frame handling of received odometry")
    deterministic_timeout_s: float = setting(
        120.0, "deterministic mode: lockstep wait per frame before failing", unit="s", low=0, low_open=True)
    map_switch: MapSwitchConfig = section(MapSwitchConfig, "switching to a new version of the map while running")

    def check_relations(self) -> None:
        if not self.odometry_key or any(c in self.odometry_key for c in "$?#") or self.odometry_key.startswith("/"):
            raise ValueError(f"runtime.odometry_key {self.odometry_key!r} is not a valid key expression "
                             "(no leading '/', no $ ? #)")


# --------------------------------------------------------------------- planner (image-goal navigation)
# (used by litevloc.runtime.planner.node / `litevloc plan`)


@dataclass(frozen=True)
class PlannerConfig(Settings):
    """The planner service (`litevloc plan`): goal localization, subgoal tracking, publishing.

    Keys (namespaced like the runtime's): subscribes `litevloc/pose`, `litevloc/goal_image`,
    `litevloc/goal_cancel`; publishes `litevloc/subgoal`, `litevloc/subgoal_base`,
    `litevloc/planner_status`.
    """

    goal: GoalParams = section(GoalParams, "placing a goal image in the map")
    tracker: TrackerParams = section(TrackerParams, "following the planned path")
    openings: OpeningParams = section(
        OpeningParams, "what `map build` / `map info` list as unmapped openings of a map's occupancy grid (where to "
        "go back)")
    publish_period_s: float = setting(
        0.0, "sensor time between subgoal messages (0 = on every fused pose)", unit="s", low=0)
    status_period_s: float = setting(
        1.0, "wall time between repeated planner status messages", unit="s", low=0, low_open=True)
    max_queued_goals: int = setting(32, "goal images queued at most", low=1)
    max_goal_bytes: int = setting(8_000_000, "goal images larger than this are rejected", unit="bytes", low=1024)


# --------------------------------------------------------------------- diagnostics
# (used by litevloc.runtime.service.diagnostics: `litevloc/diagnostics`, diagnostic_msgs/DiagnosticArray)
@dataclass(frozen=True)
class LevelThresholds(Settings):
    """WARN at or above `warn`, ERROR at or above `error` (for "lower is worse" figures the
    diagnostics compare the other way: WARN at or below `warn`, ERROR at or below `error`)."""

    warn: float = setting(description="a figure at or beyond this is WARN (at or below it where lower is worse)", low=0)
    error: float = setting(
        description="a figure at or beyond this is ERROR (at or below it where lower is worse)", low=0)


@dataclass(frozen=True)
class DiagnosticsConfig(Settings):
    """Levels of `litevloc/diagnostics` (one DiagnosticStatus per stage, queue, VLoc, tracking).

    Stage thresholds apply to the p99 execution time (ms) over the runtime's latency window:
    extract / vpr / match / pnp per VLoc query (match and pnp summed over the candidates of
    one query), fusion per odometry message, publish per published message. Queue depth is
    a fraction of capacity; any overflow (a never-drop FIFO refusing an item) is ERROR.
    VLoc rate (Hz) and acceptance (accepted / calls) are over the last diagnostics period
    and are "lower is worse"; they are only judged once `min_vloc_calls` calls were made.
    """

    enabled: bool = setting(True, "publish `litevloc/diagnostics`")
    period_s: float = setting(
        1.0, "wall time between DiagnosticArray messages, sent with the status tick", unit="s", low=0, low_open=True)
    hardware_id: str = setting("litevloc", "hardware_id of every DiagnosticStatus")
    extract_ms: LevelThresholds = section(
        lambda: LevelThresholds(500.0, 2000.0), "p99 of feature extraction per VLoc query (ms)")
    vpr_ms: LevelThresholds = section(
        lambda: LevelThresholds(300.0, 1000.0), "p99 of place recognition per VLoc query (ms)")
    match_ms: LevelThresholds = section(
        lambda: LevelThresholds(1500.0, 5000.0), "p99 of matching per VLoc query, candidates summed (ms)")
    pnp_ms: LevelThresholds = section(
        lambda: LevelThresholds(50.0, 200.0), "p99 of PnP per VLoc query, candidates summed (ms)")
    fusion_ms: LevelThresholds = section(lambda: LevelThresholds(10.0, 50.0), "p99 of fusion per odometry message (ms)")
    publish_ms: LevelThresholds = section(lambda: LevelThresholds(10.0, 50.0), "p99 of publishing per message (ms)")
    queue_fill: LevelThresholds = section(
        lambda: LevelThresholds(0.5, 0.9), "queue depth as a fraction of its capacity")
    vloc_rate_hz: LevelThresholds = section(
        lambda: LevelThresholds(0.5, 0.1), "VLoc rate over the last period (Hz; lower is worse)")
    vloc_acceptance: LevelThresholds = section(
        lambda: LevelThresholds(0.5, 0.1), "accepted / calls over the last period (lower is worse)")
    min_vloc_calls: int = setting(3, "VLoc rate and acceptance are judged only after this many calls", low=1)

    def check_relations(self) -> None:
        if not self.hardware_id:
            raise ValueError("diagnostics.hardware_id must not be empty")
        for name in ("extract_ms", "vpr_ms", "match_ms", "pnp_ms", "fusion_ms", "publish_ms", "queue_fill"):
            t = getattr(self, name)
            if not t.warn <= t.error:
                raise ValueError(f"diagnostics.{name}: need 0 <= warn <= error (finite), got {t.warn}, {t.error}")
        for name in ("vloc_rate_hz", "vloc_acceptance"):
            t = getattr(self, name)
            if not t.error <= t.warn:
                raise ValueError(f"diagnostics.{name} (lower is worse): need 0 <= error <= warn (finite), "
                                 f"got warn {t.warn}, error {t.error}")
