"""Assemble the onboard service from a configuration: map, models, localizer, fusion, bus.

Used by `litevloc run` (live or `--source` recording) and `litevloc replay --config`
(hardware-in-the-loop replay). Everything that can be missing is checked before any
thread starts, so a bad map, a missing model or an unreachable Zenoh peer is a clear
error, not a hang.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from litevloc.config.schema import LiteVLocConfig
from litevloc.hw import ros_msgs
from litevloc.hw.messages import GroundTruthPose, SourceMessage
from litevloc.models.ort import ProviderReport, provider_report
from litevloc.models.types import ProviderState
from litevloc.pipelines.evaluation.trajectory import AteResult, associate, ate
from litevloc.pipelines.fusion.online import OnlineFusion
from litevloc.pipelines.localization.vloc import VisualLocalizer
from litevloc.pipelines.topomap.io import load_map, read_manifest
from litevloc.pipelines.topomap.types import TopoMap
from litevloc.runtime.service.core import LocalizationCore
from litevloc.runtime.service.diagnostics import DiagnosticsPublisher
from litevloc.runtime.service.frame_guard import FrameGuard
from litevloc.runtime.service.fusion_port import fusion_port
from litevloc.runtime.service.lifecycle import Lifecycle
from litevloc.runtime.service.map_switch import MapSwitcher, MapVersion, SwitchableVloc
from litevloc.runtime.service.map_versions import ThreadVloc
from litevloc.runtime.service.shell import OdometryReceiverFactory, Service, ServicePorts, VlocFn
from litevloc.runtime.service.stages import call_in_low_priority_thread
from litevloc.runtime.service.vloc_process import VlocProcess, VlocWorkerSpec
from litevloc.runtime.transport.bus import Bus, LiteVLocPublisher
from litevloc.runtime.transport.ros_inputs import InitialPoseInput
from litevloc.runtime.vloc_models import check_map_models, load_bundle, second_look_for

log = logging.getLogger(__name__)


def log_provider_report(report: ProviderReport) -> None:
    """The start-up line: the onnxruntime build and each model's provider; a provider asked for and
    not in use is a WARNING."""
    log.info("models: %s", report.summary)
    if report.state is ProviderState.FALLBACK:
        log.warning("%s: see `litevloc models warmup` and docs/deployment.md (GPU: CUDA and TensorRT)",
                    report.message)
    elif report.state is ProviderState.DISTRIBUTION_CLASH:
        log.warning("%s", report.message)


@dataclass
class Recorder:
    """Collects fused poses and ground truth during a run (for TUM output and ATE)."""

    fused_t: list[int] = field(default_factory=list)
    fused_T: list[NDArray[np.float64]] = field(default_factory=list)
    gt_t: list[int] = field(default_factory=list)
    gt_T: list[NDArray[np.float64]] = field(default_factory=list)
    enabled: bool = True  # False for the long-running service: these lists grow ~200 MB per hour at 200 Hz

    def on_fused(self, fused: Any) -> None:
        if self.enabled and getattr(fused, "initialised", True):
            self.fused_t.append(int(fused.t_ns))
            self.fused_T.append(np.asarray(fused.T_map_base, dtype=np.float64))

    def on_ground_truth(self, gt: GroundTruthPose) -> None:
        if not self.enabled:
            return
        self.gt_t.append(gt.t_ns)
        self.gt_T.append(gt.T_world_camera)

    def camera_ate(self, T_base_camera: NDArray[np.float64], max_dt_s: float = 0.006) -> AteResult | None:
        """The fused camera positions (`T_map_base @ T_base_camera`) against the ground truth
        recorded beside them, associated within `max_dt_s`, no alignment (the map frame is the
        ground truth's); None with fewer than 3 associated pairs."""
        if not self.fused_t or not self.gt_t:
            return None
        cam = np.stack(self.fused_T) @ T_base_camera
        ia, ib = associate(np.array(self.fused_t) * 1e-9, np.array(self.gt_t) * 1e-9, max_dt_s)
        return ate(cam[ia], np.stack(self.gt_T)[ib], align=False) if len(ia) >= 3 else None


class App(Lifecycle):
    """The onboard node: map, models, localizer (or its process), fusion, view, bus, publisher and
    the `Service` that runs them, each held by the node's lifecycle (`runtime.service.lifecycle`).

    configure: the VLoc (models and map in this process, or the VLoc child process), fusion, the
    live view, the Zenoh session, the publishers and the service's wiring; activate: the live
    inputs on the bus (/initialpose) and the models' provider line; deactivate: stop the service;
    cleanup: release all of it, newest first. `build_app` configures and activates one.
    `request_map_switch`: a new version of the map, switched to while running (`runtime.service.map_switch`)."""

    def __init__(self, cfg: LiteVLocConfig, map_path: Path, source: Iterable[SourceMessage], rate: float, *,
                 on_fused: Callable[[Any], None] | None = None, record: bool = True,
                 view_spawn: bool = False, view_save: Path | None = None,
                 map_name: str | None = None, map_version: str | None = None) -> None:
        super().__init__()
        self.cfg, self.map_path, self.source, self.rate = cfg, Path(map_path), source, rate
        self.map_name, self.map_version = map_name, map_version  # as the map service names them, if it does
        self.on_fused, self.view_spawn, self.view_save = on_fused, view_spawn, view_save
        self.recorder = Recorder(enabled=record)
        self.T_base_camera: NDArray[np.float64] = cfg.fusion.T_base_camera()
        self._thread_vloc: ThreadVloc | None = None  # None when VLoc runs in its own process (`vloc_process`)
        self.map_switcher: MapSwitcher | None = None  # `request_map_switch`
        self.vloc_process: VlocProcess | None = None  # runtime.vloc_process: the child that runs the localizer
        self.view: Any = None  # runtime.service.view.LiveView with --view / --view-save
        self.fusion = OnlineFusion(cfg.fusion.params, self.T_base_camera)
        self._topomap: TopoMap | None = None

    @property
    def localizer(self) -> VisualLocalizer | None:
        """The localizer on the map in use (None when VLoc runs in its own process)."""
        return None if self._thread_vloc is None else self._thread_vloc.localizer

    def request_map_switch(self, path: Path, name: str, version: str) -> None:
        """Switch to the map version in folder `path` without a restart (thread-safe, returns at
        once): loaded and verified in the background, switched to between two VLoc results, refused
        (counted, logged, in the status's `map` entry) if it fails; see `runtime.service.map_switch`."""
        if self.map_switcher is None:
            raise RuntimeError("request_map_switch before the node was configured")
        self.map_switcher.request(Path(path), name, version)

    @property
    def wants_view(self) -> bool:
        return self.view_spawn or self.view_save is not None

    def close(self) -> None:
        """Release everything the node holds (`cleanup`)."""
        self.cleanup()

    # ------------------------------------------------------------------ configure
    def on_configure(self) -> None:
        backend = self._configure_vloc()
        if self.wants_view:
            self.view = self.hold(self._open_view())
        self.bus = self.hold(Bus(self.cfg.zenoh, rt_priority=self.cfg.runtime.transport_rt_priority))
        self.publisher = self.hold(self._open_publisher())
        current = MapVersion(self.map_path, self.map_name, self.map_version, map_id(self.map_path), self._map_nodes())
        self.map_switcher = self.hold(MapSwitcher(backend, current, map_id_of=map_id, nice=self.cfg.runtime.vloc_nice))
        vloc_fn = FrameGuard(self.map_switcher)
        if self.view is not None:
            vloc_fn = self.view.wrap_vloc(vloc_fn)
            self.publisher.on_status = self.view.put_status
        self.service = self._wire_service(vloc_fn)

    def _configure_vloc(self) -> SwitchableVloc:
        """The VLoc callable: a child process that loads the models and the map itself (realtime and
        deterministic modes with `runtime.vloc_process`; this process then loads the map only for the
        live view), or the localizer built here with its models."""
        cfg = self.cfg
        if cfg.runtime.vloc_process and cfg.runtime.mode != "sequential":
            self.vloc_process = self.hold(VlocProcess(VlocWorkerSpec(cfg, self.map_path)))
            self._topomap = load_map(self.map_path) if self.wants_view else None
            return self.vloc_process
        models = dataclasses.replace(cfg.models, intra_op_threads=cfg.runtime.ort_intra_op_threads)
        # Sessions made in a low-priority thread: their intra-op threads inherit the VLoc thread's nice.
        bundle = call_in_low_priority_thread(lambda: load_bundle(models), cfg.runtime.vloc_nice)
        topomap = self._topomap = check_map_models(load_map(self.map_path), bundle)
        localizer = VisualLocalizer(topomap, cfg.localization, bundle.extract, bundle.describe, bundle.match,
                                    second_look=second_look_for(topomap, models, cfg.localization, bundle))
        self._thread_vloc = ThreadVloc(topomap, localizer, bundle, cfg)
        return self._thread_vloc

    def _open_view(self) -> Any:
        """The live view (`runtime.service.view`, imported only then), fed off the hot path from the
        VLoc callable, the fused-pose hook and the status tick."""
        from litevloc.runtime.service.view import LiveView

        nice = self.cfg.runtime.vloc_nice
        # Made in a thread at VLoc's nice: the view thread and Rerun's own threads (batcher, sinks)
        # inherit it. Not lower: a view thread preempted while it holds the GIL stalls fusion
        # (measured at nice 19: fused-pose p99 x3; at VLoc's nice 10: x1.0, see bench/runtime.py --view).
        return call_in_low_priority_thread(
            lambda: LiveView(save=self.view_save, spawn=self.view_spawn, topomap=self._topomap,
                             T_base_camera=self.T_base_camera, nice=nice), nice)

    def _map_nodes(self) -> int:
        # (with the VLoc process, the child validated the whole map; the node count is the manifest's)
        topomap = self._topomap
        return topomap.n_nodes if topomap is not None else int(read_manifest(self.map_path)["nodes"])

    def _open_publisher(self) -> LiteVLocPublisher:
        diagnostics = DiagnosticsPublisher(self.cfg.diagnostics, map_id(self.map_path), self._map_nodes())
        return LiteVLocPublisher(self.bus, tf=self.cfg.zenoh.tf, diagnostics=diagnostics,
                                 T_base_camera=self.T_base_camera)

    def _wire_service(self, vloc_fn: VlocFn) -> Service:
        cfg, recorder, view, on_fused = self.cfg, self.recorder, self.view, self.on_fused

        def fused_hook(f: Any) -> None:
            recorder.on_fused(f)
            if on_fused is not None:
                on_fused(f)
            if view is not None:
                view.put_fused(f)

        # The smoother update a fusion keyframe needs (~1-3 ms, every fusion.keyframe_period_s) runs
        # after the pose is handed on, not before (runtime.defer_fusion_updates).
        port = fusion_port(self.fusion, defer_updates=cfg.runtime.defer_fusion_updates)
        core = LocalizationCore(port, cfg.runtime, T_base_camera=self.T_base_camera, on_fused=fused_hook)
        ports = ServicePorts(self.publisher, self._odometry_receiver(), recorder.on_ground_truth)
        service = Service(self.source, vloc_fn, core, ports, rate=self.rate)
        if self.map_switcher is not None:
            service.map_report = self.map_switcher.report
        return service

    def _odometry_receiver(self) -> OdometryReceiverFactory | None:
        """`runtime.odometry_input: zenoh`: the robot's odometry from the bus, made when the run starts."""
        rt, bus = self.cfg.runtime, self.bus
        if rt.odometry_input != "zenoh":
            return None
        from litevloc.hw.odometry import OdometryReceiver

        # bridge: the literal key; rmw_zenoh: the ROS topic `odometry_key` in the node's namespace
        odom_key = rt.odometry_key if not bus.rmw_zenoh else bus.key(rt.odometry_key, ros_msgs.ODOMETRY)

        def zenoh_odometry(sink: Callable[[Any], None]) -> Any:
            if bus.rmw_zenoh:  # announce the subscription to the ROS graph
                bus.announce_subscription(rt.odometry_key, ros_msgs.ODOMETRY)
            return OdometryReceiver(bus.session, odom_key, sink, rt.odometry_checks)

        return zenoh_odometry

    # ------------------------------------------------------------------ activate / deactivate
    def on_activate(self) -> None:
        service = self.service
        report_of: Callable[[], ProviderReport] | None = provider_report  # live: the second look joins when loaded
        if self.vloc_process is not None:
            child_report = self.vloc_process.provider_report  # the child's sessions, when it had loaded them
            report_of = None if child_report is None else (lambda: child_report)
        if report_of is not None:
            service.models_report = report_of
            log_provider_report(report_of())
        if self.cfg.zenoh.initial_pose.enabled:
            service.inputs["initial_pose"] = self.hold(InitialPoseInput(self.bus, service.core, self.cfg.zenoh))

    def on_deactivate(self) -> None:
        self.service.stop("node deactivated")


def with_endpoints(cfg: LiteVLocConfig, listen: list[str], connect: list[str], namespace: str | None) -> LiteVLocConfig:
    """Command-line endpoints replace the config's (validated again)."""
    z = cfg.zenoh
    changes: dict[str, Any] = {}
    if listen:
        changes["listen"] = tuple(listen)
    if connect:
        changes["connect"] = tuple(connect)
    if namespace is not None:
        changes["namespace"] = namespace
    return dataclasses.replace(cfg, zenoh=dataclasses.replace(z, **changes)) if changes else cfg


def map_id(map_path: Path) -> str:
    """`<folder name>@<first 12 hex of sha256(manifest.json)>`: names the exact map content
    (the manifest holds every file's sha256), for `litevloc/diagnostics`."""
    import hashlib

    digest = hashlib.sha256((Path(map_path) / "manifest.json").read_bytes()).hexdigest()[:12]
    return f"{Path(map_path).resolve().name}@{digest}"


def build_app(
    cfg: LiteVLocConfig, map_path: Path, source: Iterable[SourceMessage], rate: float,
    on_fused: Callable[[Any], None] | None = None, record: bool = True,
    view_spawn: bool = False, view_save: Path | None = None,
    map_name: str | None = None, map_version: str | None = None,
) -> App:
    """The onboard node configured and activated (nothing runs yet: `app.service.run()`, then
    `app.close()`). Everything that can be missing is checked here, before any thread starts;
    on a failure what was acquired is released (newest first) and the error raised."""
    app = App(cfg, map_path, source, rate, on_fused=on_fused, record=record, view_spawn=view_spawn,
              view_save=view_save, map_name=map_name, map_version=map_version)
    app.configure()
    app.activate()
    return app
