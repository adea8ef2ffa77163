"""The onboard localization core: every decision between the sensor messages and what is
published, single-threaded and free of I/O.

`LocalizationCore` owns the tracking state (one state machine, with reasons), the fusion
callbacks, the map->odom throttle, the counters of what it decided and the core part of the
status report. Its two steps return typed outputs; the shell (`runtime.service.shell.Service`)
runs them in threads (realtime, deterministic) or inline (sequential) and publishes the
outputs, so every mode takes the same decisions from the same inputs.

```
odometry(odom, t_in_ns)  -> [PoseOut, MapToOdomOut]   (fusion thread)
vloc_result(result)      -> [VlocOut]                  (fusion thread)
prior(t_frame_ns)        -> VlocPrior | None           (vloc thread: reads a snapshot and a locked buffer)
```

What is published is decided here, finally: the outputs carry the exact pose, covariance and
stamp to send, and the publisher (`runtime.transport.bus.LiteVLocPublisher`) only serialises
them. Tracking loss (`RuntimeConfig.lost_policy`): `"flag"` raises every diagonal entry of the
pose covariance to at least `lost_variance` (frame ids unchanged; map->odom goes on with its last
good value); `"withhold"` emits no pose and no map->odom while LOST (counted as `poses_withheld`).
Before fusion is initialised nothing is emitted under either policy (state INIT).

The VLoc thread reads fusion's state through one `FusionSnapshot`, a frozen value the fusion
thread replaces whole after each step, so a prior never mixes two fusion steps.

Tracking state (`tracking_state()`): `pipelines.localization.tracking.published_state` of the
localizer's state reported with its latest result (`VlocOutcome.tracking_state`, set by the
VLoc stage right after the query: no state is read across threads), whether fusion is
initialised, and the sensor time (odometry stamps) since fusion last accepted a VLoc fix.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from enum import Enum
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from litevloc.base.geometry import invert, is_rigid
from litevloc.base.params.drift import T_BASE_CAMERA_OPTICAL
from litevloc.config.schema import RuntimeConfig
from litevloc.hw.messages import Odometry
from litevloc.pipelines.localization.tracking import TrackingState, published_state
from litevloc.runtime.service.diagnostics import VlocStageTimes
from litevloc.runtime.service.vloc_prior import OdometryHistory, VlocPrior, prior_at
from litevloc.runtime.transport.ros_interface import InitialPose

F64 = NDArray[np.float64]

#: counters the core owns (the shell owns the source, VLoc-call and publishing counters)
CORE_COUNTERS = ("vloc_accepted", "vloc_rejected", "fusion_accepted", "fusion_rejected", "odometry_fused",
                 "odometry_rejected", "odometry_gaps", "vloc_votes", "fusion_initialised_by_votes",
                 "initial_poses_applied", "initial_poses_expired", "poses_withheld")


class LostPolicy(str, Enum):
    """How a pose is published while LOST (`RuntimeConfig.lost_policy`)."""

    FLAG = "flag"  # published, covariance diagonal raised to at least `lost_variance`
    WITHHOLD = "withhold"  # not published (nor map->odom)


class ProvisionalLike(Protocol):
    """A single-keyframe GL pose offered to fusion as an initialisation vote."""

    @property
    def T_map_camera(self) -> NDArray[np.floating]: ...

    @property
    def covariance(self) -> NDArray[np.floating] | None: ...


class VlocOutcome(Protocol):
    """What the service needs from one VLoc query (`pipelines.localization.results.LocalizationResult`).

    `T_map_camera` 4x4 (metres), None unless accepted; `covariance` 6x6 camera-frame
    perturbation (tx, ty, tz, rx, ry, rz); `timings_ms` per stage; `provisional` only on
    rejected GL results; `tracking_state` the localizer's state after this query (None = unknown).
    """

    @property
    def t_ns(self) -> int: ...

    @property
    def accepted(self) -> bool: ...

    @property
    def reason(self) -> str: ...

    @property
    def T_map_camera(self) -> NDArray[np.floating] | None: ...

    @property
    def covariance(self) -> NDArray[np.floating] | None: ...

    @property
    def timings_ms(self) -> Mapping[str, float]: ...

    @property
    def provisional(self) -> ProvisionalLike | None: ...

    @property
    def tracking_state(self) -> TrackingState | None: ...


class FusedPoseLike(Protocol):
    """A fused pose (`pipelines.fusion.online.FusedPose`): 4x4 `T_map_base`, `T_map_odom`, 6x6
    `covariance` (GTSAM or ROS order, see `covariance_to_ros`); `initialised` False before the
    first fix."""

    @property
    def t_ns(self) -> int: ...

    @property
    def T_map_base(self) -> NDArray[np.floating]: ...

    @property
    def T_map_odom(self) -> NDArray[np.floating]: ...

    @property
    def covariance(self) -> NDArray[np.floating] | None: ...

    @property
    def initialised(self) -> bool: ...


class FusionUpdateLike(Protocol):
    """Fusion's answer to a VLoc fix (`pipelines.fusion.online.VlocUpdate`)."""

    @property
    def accepted(self) -> bool: ...

    @property
    def reason(self) -> str: ...


OdometryFn = Callable[[Odometry], FusedPoseLike | None]
VlocUpdateFn = Callable[[VlocOutcome], FusionUpdateLike | None]


@dataclass(frozen=True, eq=False)
class PoseOut:
    """Publish the fused pose as it is. `covariance`: 6x6 ROS order, already flagged when `lost`
    (policy "flag"); `t_in_ns`: wall clock when its odometry entered the service."""

    t_ns: int
    T_map_base: NDArray[np.floating]
    covariance: NDArray[np.floating] | None
    lost: bool
    t_in_ns: int


@dataclass(frozen=True, eq=False)
class MapToOdomOut:
    """Publish the map->odom correction (4x4)."""

    t_ns: int
    T_map_odom: NDArray[np.floating]
    lost: bool


@dataclass(frozen=True, eq=False)
class VlocOut:
    """Publish a VLoc fix that fusion accepted (4x4 `T_map_camera`, 6x6 covariance or None)."""

    t_ns: int
    T_map_camera: NDArray[np.floating]
    covariance: NDArray[np.floating] | None


CoreOutput = PoseOut | MapToOdomOut | VlocOut


@dataclass(frozen=True)
class FusionPort:
    """The fusion the core drives, in the fusion thread only (`runtime.service.fusion_port`).

    `on_odometry` / `on_vloc`: one message in, fusion's answer out; `after_odometry`: work the
    pose must not wait for (a deferred smoother update), run after the pose was handed on;
    `covariance_to_ros`: the fused covariance's conversion to ROS order (None: already ROS order)."""

    on_odometry: OdometryFn
    on_vloc: VlocUpdateFn
    after_odometry: Callable[[], None] | None = None
    covariance_to_ros: Callable[[F64], F64] | None = None


@dataclass(frozen=True, eq=False)
class FusionSnapshot:
    """Fusion's state as the VLoc thread reads it (for the prior), replaced whole, never changed.

    `fused`: the latest fused pose (None before fusion's first answer); `covariance`: its 6x6 in
    ROS order; `last_fix_ns`: sensor stamp of the latest fix fusion accepted; `sensor_now_ns`: the
    latest odometry stamp."""

    fused: FusedPoseLike | None = None
    covariance: NDArray[np.floating] | None = None
    last_fix_ns: int | None = None
    sensor_now_ns: int | None = None


def flag_covariance(cov: NDArray[np.floating] | None, variance: float) -> NDArray[np.float64]:
    """Covariance with every diagonal entry raised to at least `variance` (the LOST flag)."""
    c = np.zeros((6, 6)) if cov is None else np.array(cov, dtype=np.float64).reshape(6, 6)
    d = np.arange(6)
    c[d, d] = np.maximum(np.nan_to_num(c[d, d], nan=variance), variance)
    return c


class LocalizationCore:
    """See the module docstring. Not thread-safe except `prior()`, which the VLoc thread may
    call while the fusion thread steps the core."""

    def __init__(
        self,
        fusion: FusionPort,
        params: RuntimeConfig | None = None,
        *,
        T_base_camera: NDArray[np.floating] = T_BASE_CAMERA_OPTICAL,
        on_fused: Callable[[FusedPoseLike], None] | None = None,
    ) -> None:
        self.fusion, self.params = fusion, params or RuntimeConfig()
        self.lost_policy = LostPolicy(self.params.lost_policy)
        self.T_base_camera = np.asarray(T_base_camera, dtype=np.float64)
        self.on_fused = on_fused
        self.counters: dict[str, int] = dict.fromkeys(CORE_COUNTERS, 0)
        self.poses_flagged = 0  # poses published with the LOST covariance (reported with the bus status)
        self.snapshot = FusionSnapshot()  # written by the fusion thread only, read by the VLoc thread
        # odometry poses (fused, or before fusion starts), for the prior at a frame's stamp
        self.odometry_history = OdometryHistory()
        # the latest fix the localizer accepted while fusion was not yet initialised: (t_ns, T_map_camera)
        self._pre_init_fix: tuple[int, NDArray[np.float64]] | None = None
        self.last_vloc_reason: str | None = None
        self.last_fusion_reason: str | None = None
        self.localizer_state: TrackingState | None = None  # as reported with the latest VLoc result
        self.vloc_times = VlocStageTimes(self.params.latency_window)  # per-query extract/vpr/match/pnp ms
        self._last_m2o_ns: int | None = None
        self._m2o_due = False
        # an initial pose (set by the shell's /initialpose subscriber, read by the VLoc thread):
        # [pose, sensor time it arrived at, stamp of the first frame queried with it] until a fix from
        # such a query is accepted or its `hold_s` passes
        self._initial: list[Any] | None = None
        self._initial_lock = threading.Lock()

    @property
    def last_fused(self) -> FusedPoseLike | None:
        return self.snapshot.fused

    @property
    def sensor_now_ns(self) -> int | None:
        return self.snapshot.sensor_now_ns

    @property
    def last_vloc_accept_ns(self) -> int | None:
        return self.snapshot.last_fix_ns

    # ------------------------------------------------------------------ steps
    def odometry(self, odom: Odometry, t_in_ns: int) -> list[CoreOutput]:
        """One odometry message through fusion; the pose (and map->odom when due) to publish."""
        snap = self.snapshot
        if snap.sensor_now_ns is not None and (odom.t_ns - snap.sensor_now_ns) * 1e-9 > \
                self.params.odometry_checks.max_gap_s:
            self.counters["odometry_gaps"] += 1  # (the Zenoh receiver counts its own; this is every input)
        self.snapshot = snap = FusionSnapshot(snap.fused, snap.covariance, snap.last_fix_ns, odom.t_ns)
        fused = self.fusion.on_odometry(odom)
        self.counters["odometry_fused"] += 1
        if fused is None:
            if snap.fused is not None:  # fusion refused it (time not increasing, bad pose)
                self.counters["odometry_rejected"] += 1
            elif is_rigid(odom.T_odom_base, atol=1e-4):
                # fusion answers nothing until it starts; the first fix is carried by this odometry
                self.odometry_history.add(odom.t_ns, odom.T_odom_base)
            return []
        self.odometry_history.add(odom.t_ns, odom.T_odom_base)
        cov = self._ros_covariance(fused) if fused.initialised else None
        self.snapshot = FusionSnapshot(fused, cov, snap.last_fix_ns, odom.t_ns)
        if self.on_fused is not None:
            self.on_fused(fused)
        if not fused.initialised:
            return []
        self._pre_init_fix = None
        return self._publish_decision(fused, cov, t_in_ns)

    def _publish_decision(self, fused: FusedPoseLike, cov: NDArray[np.floating] | None,
                          t_in_ns: int) -> list[CoreOutput]:
        """What goes out for one initialised fused pose: the pose (flagged or withheld while LOST,
        see the module docstring) and, every `map_to_odom_period_s` or after a fix, map->odom."""
        lost = self.tracking_state()[0] == TrackingState.LOST
        withhold = lost and self.lost_policy is LostPolicy.WITHHOLD
        t = int(fused.t_ns)
        outs: list[CoreOutput] = []
        if withhold:
            self.counters["poses_withheld"] += 1
        else:
            if lost:
                self.poses_flagged += 1
                cov = flag_covariance(cov, self.params.lost_variance)
            outs.append(PoseOut(t, fused.T_map_base, cov, lost, t_in_ns))
        due = self._m2o_due or self._last_m2o_ns is None or (
            (t - self._last_m2o_ns) * 1e-9 >= self.params.map_to_odom_period_s)
        if due:
            self._m2o_due = False
            self._last_m2o_ns = t
            if not withhold:
                outs.append(MapToOdomOut(t, fused.T_map_odom, lost))
        return outs

    def after_odometry(self) -> None:
        """Fusion's deferred work (`FusionPort.after_odometry`), once the pose was handed on."""
        if self.fusion.after_odometry is not None:
            self.fusion.after_odometry()

    def set_initial_pose(self, pose: InitialPose) -> None:
        """An accepted initial pose: the next VLoc queries are GL bounded by it (thread-safe)."""
        with self._initial_lock:
            self._initial = [pose, self.sensor_now_ns, None]
            self.counters["initial_poses_applied"] += 1

    def _initial_region_at(self, t_frame_ns: int) -> VlocPrior | None:
        """The pending initial pose as a prior with a search region; None when there is none or it expired."""
        with self._initial_lock:
            if self._initial is None:
                return None
            pose, since, first = self._initial
            if since is not None and (t_frame_ns - since) * 1e-9 > pose.hold_s:
                self._initial = None
                self.counters["initial_poses_expired"] += 1
                return None
            if first is None:
                self._initial[2] = t_frame_ns
        T_map_camera = pose.T_map_base @ self.T_base_camera
        return VlocPrior(T_map_camera, 0.0, False, region=pose.region(self.T_base_camera))

    def vloc_result(self, res: VlocOutcome) -> list[CoreOutput]:
        """One VLoc result: accepted fixes go to fusion; a provisional GL pose goes in as a vote."""
        if res.accepted:
            with self._initial_lock:  # a fix from a query bounded by the initial pose: tracking takes over
                if self._initial is not None and self._initial[2] is not None and res.t_ns >= self._initial[2]:
                    self._initial = None
        self.vloc_times.add(res.timings_ms)
        self.last_vloc_reason = str(res.reason)
        if res.tracking_state:
            self.localizer_state = res.tracking_state
        if not res.accepted or res.T_map_camera is None:
            self.counters["vloc_rejected"] += 1
            if res.provisional is not None:
                self._vote(res)
            return []
        self.counters["vloc_accepted"] += 1
        self.note_fix(res)
        update = self.fusion.on_vloc(res)
        self.last_fusion_reason = None if update is None else str(update.reason)
        if update is not None and not update.accepted:
            self.counters["fusion_rejected"] += 1
            return []
        self.counters["fusion_accepted"] += 1
        self._fix_accepted(int(res.t_ns))
        return [VlocOut(int(res.t_ns), res.T_map_camera, res.covariance)]

    def _vote(self, res: VlocOutcome) -> None:
        """A provisional (single-keyframe) GL pose: an initialisation vote for fusion only."""
        self.counters["vloc_votes"] += 1
        update = self.fusion.on_vloc(res)
        if update is not None and update.accepted:
            self.counters["fusion_initialised_by_votes"] += 1
            self._fix_accepted(int(res.t_ns))  # the LOST timer starts here

    def _ros_covariance(self, fused: FusedPoseLike) -> NDArray[np.floating] | None:
        """The fused pose's 6x6 covariance in ROS order (see `covariance_to_ros`), None if it has none."""
        cov, to_ros = fused.covariance, self.fusion.covariance_to_ros
        if cov is not None and to_ros is not None:
            cov = to_ros(np.asarray(cov, dtype=np.float64))
        return cov

    def _fix_accepted(self, t_ns: int) -> None:
        snap = self.snapshot
        last = snap.last_fix_ns
        self.snapshot = FusionSnapshot(snap.fused, snap.covariance, t_ns if last is None else max(last, t_ns),
                                       snap.sensor_now_ns)
        self._m2o_due = True

    # ------------------------------------------------------------------ reads
    def prior(self, t_frame_ns: int | None = None) -> VlocPrior | None:
        """The VLoc prior at `t_frame_ns`: the latest `T_map_odom` applied to the odometry
        interpolated at the frame's stamp, times `T_base_camera`, with its age (seconds since
        the last fix fusion accepted); at the newest odometry when None. Before fusion is
        initialised: the last accepted fix carried by odometry (see `_carried_pre_init_fix`), or
        None. While an initial pose is pending, that pose with its search region."""
        snap = self.snapshot  # read once: one fusion step's state
        f = snap.fused
        t_now = (int(f.t_ns) if f is not None else snap.sensor_now_ns or 0) if t_frame_ns is None else int(t_frame_ns)
        initial = self._initial_region_at(t_now)
        if initial is not None:
            return initial
        if f is None or not f.initialised:
            return self._carried_pre_init_fix(t_now)
        t = int(f.t_ns) if t_frame_ns is None else int(t_frame_ns)
        got = prior_at(t, f.T_map_odom, self.odometry_history, self.T_base_camera, snap.last_fix_ns,
                       snap.covariance)
        if got is None:  # no odometry history around that stamp: the latest fused pose
            return VlocPrior(np.asarray(f.T_map_base, dtype=np.float64) @ self.T_base_camera, 0.0, False)
        return got

    def note_fix(self, res: VlocOutcome) -> None:
        """Remember an accepted fix while fusion has not started, for `_carried_pre_init_fix`. The
        VLoc thread calls it as soon as the result exists: the fusion thread may take the result
        later than the VLoc thread asks for the next frame's prior."""
        if not res.accepted or res.T_map_camera is None:
            return
        f, fix = self.last_fused, self._pre_init_fix
        if (f is None or not f.initialised) and (fix is None or int(res.t_ns) > fix[0]):
            self._pre_init_fix = (int(res.t_ns), np.asarray(res.T_map_camera, dtype=np.float64))

    def _carried_pre_init_fix(self, t_frame_ns: int) -> VlocPrior | None:
        """Before fusion starts (it waits for agreeing fixes): the last accepted fix carried to
        `t_frame_ns` by the odometry since, aged from its stamp; None without one or without
        odometry. Without it the localizer's prior is its last pose, where the robot was."""
        fix = self._pre_init_fix
        if fix is None:
            return None
        got = self.odometry_history.at(fix[0])
        if got is None:
            return None
        T_odom_base, _ = got
        T_map_odom = fix[1] @ invert(self.T_base_camera) @ invert(T_odom_base)
        return prior_at(t_frame_ns, T_map_odom, self.odometry_history, self.T_base_camera, fix[0])

    def tracking_state(self) -> tuple[TrackingState, list[str]]:
        """(INIT | TRACKING | LOST, reasons); see the module docstring."""
        f = self.last_fused
        now, last = self.sensor_now_ns, self.last_vloc_accept_ns
        since_fix_s = (now - last) * 1e-9 if now is not None and last is not None else None
        return published_state(self.localizer_state, f is not None and f.initialised, since_fix_s,
                               self.params.lost_after_s)

    def report(self) -> dict[str, Any]:
        """The core's part of the status report (JSON-able values)."""
        state, reasons = self.tracking_state()
        c = self.counters
        if c["odometry_rejected"]:
            reasons.append(f"fusion rejected {c['odometry_rejected']} odometry message(s) "
                           "(time not increasing or invalid pose)")
        out: dict[str, Any] = {
            "state": str(state),
            "reasons": reasons,
            "counters": dict(c),
            "last_vloc_reason": self.last_vloc_reason,
            "last_fusion_reason": self.last_fusion_reason,
            "sensor_time_ns": self.sensor_now_ns,
            "vloc_stages": self.vloc_times.summary(),
        }
        if self.localizer_state:
            out["vloc_state"] = str(self.localizer_state)
        return out
