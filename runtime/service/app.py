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
from litevloc.pipelines.fusion.online import OnlineFusion
from litevloc.pipelines.localization.vloc import VisualLocalizer
from litevloc.pipelines.topomap.io import load_map, read_manifest
from litevloc.pipelines.topomap.types import TopoMap
from litevloc.runtime.service.diagnostics import DiagnosticsPublisher
from litevloc.runtime.service.frame_guard import FrameGuard
from litevloc.runtime.service.shell import Service, VlocFn, fusion_callables, localizer_callable
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


@dataclass
class App:
    service: Service
    bus: Bus
    localizer: VisualLocalizer | None  # None when VLoc runs in its own process (`vloc_process`)
    fusion: OnlineFusion
    recorder: Recorder
    T_base_camera: NDArray[np.float64]
    view: Any = None  # runtime.service.view.LiveView with --view / --view-save
    vloc_process: VlocProcess | None = None  # runtime.vloc_process: the child that runs the localizer

    def close(self) -> None:
        self.bus.close()
        if self.vloc_process is not None:
            self.vloc_process.close()
        if self.view is not None:
            self.view.close()


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
) -> App:
    """Load map and models, open the bus, and wire the service (nothing runs yet).

    `view_spawn` / `view_save`: the live view (`runtime.service.view`, imported only then), fed off
    the hot path from the VLoc callable, the fused-pose hook and the status tick.

    With `runtime.vloc_process` (realtime and deterministic modes) the models and the map are
    loaded by the VLoc child process (`runtime.vloc_process`), which is started and has loaded
    them when this returns; this process loads the map only for the live view."""
    localizer: VisualLocalizer | None = None
    vloc_proc: VlocProcess | None = None
    topomap: TopoMap | None
    inner_vloc: VlocFn
    if cfg.runtime.vloc_process and cfg.runtime.mode != "sequential":
        vloc_proc = VlocProcess(VlocWorkerSpec(cfg, Path(map_path)))
        inner_vloc = vloc_proc
        topomap = load_map(map_path) if (view_spawn or view_save is not None) else None
    else:
        models = dataclasses.replace(cfg.models, intra_op_threads=cfg.runtime.ort_intra_op_threads)
        # Sessions made in a low-priority thread: their intra-op threads inherit the VLoc thread's nice.
        bundle = call_in_low_priority_thread(lambda: load_bundle(models), cfg.runtime.vloc_nice)
        topomap = check_map_models(load_map(map_path), bundle)
        localizer = VisualLocalizer(topomap, cfg.localization, bundle.extract, bundle.describe, bundle.match,
                                    second_look=second_look_for(topomap, models, cfg.localization, bundle))
        inner_vloc = localizer_callable(localizer)
    T_base_camera = cfg.fusion.T_base_camera()
    fusion = OnlineFusion(cfg.fusion.params, T_base_camera)
    recorder = Recorder(enabled=record)
    view = None
    if view_spawn or view_save is not None:
        from litevloc.runtime.service.view import LiveView

        # Made in a thread at VLoc's nice: the view thread and Rerun's own threads (batcher, sinks)
        # inherit it. Not lower: a view thread preempted while it holds the GIL stalls fusion
        # (measured at nice 19: fused-pose p99 x3; at VLoc's nice 10: x1.0, see bench/runtime.py --view).
        view = call_in_low_priority_thread(
            lambda: LiveView(save=view_save, spawn=view_spawn, topomap=topomap, T_base_camera=T_base_camera,
                             nice=cfg.runtime.vloc_nice), cfg.runtime.vloc_nice)
    try:
        bus = Bus(cfg.zenoh)
    except Exception:
        if vloc_proc is not None:
            vloc_proc.close()
        raise
    try:
        # (with the VLoc process, the child validated the whole map; the node count is the manifest's)
        n_nodes = topomap.n_nodes if topomap is not None else int(read_manifest(Path(map_path))["nodes"])
        diagnostics = DiagnosticsPublisher(cfg.diagnostics, map_id(map_path), n_nodes)
        publisher = LiteVLocPublisher(bus, cfg.runtime.lost_policy, cfg.runtime.lost_variance, cfg.zenoh.tf,
                                      diagnostics=diagnostics, T_base_camera=T_base_camera)
        # The smoother update a fusion keyframe needs (~1-3 ms, every fusion.keyframe_period_s) runs
        # after the pose is handed on, not before (runtime.defer_fusion_updates).
        defer = cfg.runtime.defer_fusion_updates
        on_odom, on_vloc = fusion_callables(fusion, defer_updates=defer)
        receiver: Callable[[Callable[[Any], None]], Any] | None = None
        if cfg.runtime.odometry_input == "zenoh":
            from litevloc.hw.odometry import OdometryReceiver

            # bridge: the literal key; rmw_zenoh: the ROS topic `odometry_key` in the node's namespace
            odom_key = cfg.runtime.odometry_key if not bus.rmw_zenoh else bus.key(cfg.runtime.odometry_key,
                                                                                  ros_msgs.ODOMETRY)

            def zenoh_odometry(sink: Callable[[Any], None]) -> Any:
                if bus.rmw_zenoh:  # announce the subscription to the ROS graph
                    bus.announce_subscription(cfg.runtime.odometry_key, ros_msgs.ODOMETRY)
                return OdometryReceiver(bus.session, odom_key, sink, cfg.runtime.odometry_checks)

            receiver = zenoh_odometry

        def fused_hook(f: Any) -> None:
            recorder.on_fused(f)
            if on_fused is not None:
                on_fused(f)
            if view is not None:
                view.put_fused(f)

        vloc_fn = FrameGuard(inner_vloc)
        if view is not None:
            vloc_fn = view.wrap_vloc(vloc_fn)
            publisher.on_status = view.put_status

        service = Service(
            source, vloc_fn, on_odom, on_vloc, publisher, cfg.runtime, rate=rate,
            T_base_camera=T_base_camera, odometry_receiver=receiver,
            on_ground_truth=recorder.on_ground_truth, on_fused=fused_hook,
            after_odometry=fusion.flush if defer else None,
        )
        report_of: Callable[[], ProviderReport] | None = provider_report  # live: the second look joins when loaded
        if vloc_proc is not None:
            child_report = vloc_proc.provider_report  # the child's sessions, when it had loaded them
            report_of = None if child_report is None else (lambda: child_report)
        if report_of is not None:
            service.models_report = report_of
            log_provider_report(report_of())
        if cfg.zenoh.initial_pose.enabled:
            service.inputs["initial_pose"] = InitialPoseInput(bus, service.core, cfg.zenoh)
    except Exception:
        bus.close()
        if vloc_proc is not None:
            vloc_proc.close()
        if view is not None:
            view.close()
        raise
    return App(service, bus, localizer, fusion, recorder, T_base_camera, view, vloc_proc)

