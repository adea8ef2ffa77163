"""Fakes for service tests: a synthetic recording, a VLoc that reads ground truth, a tiny fusion."""

from __future__ import annotations

import time
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from litevloc.base.geometry import invert, make_T, so3_exp
from litevloc.base.params.drift import T_BASE_CAMERA_OPTICAL
from litevloc.config.schema import RuntimeConfig
from litevloc.hw.messages import Message, Odometry, RgbdFrame, StreamStats
from litevloc.runtime.service.core import FusionPort, LocalizationCore
from litevloc.runtime.service.shell import Service, ServicePorts

MS = 1_000_000
T_MAP_ODOM_TRUE = make_T(so3_exp(np.array([0.0, 0.0, 0.7])), np.array([2.0, -1.0, 0.1]))


def T_odom_base_at(t_ns: int) -> np.ndarray:
    s = t_ns * 1e-9
    return make_T(so3_exp(np.array([0.0, 0.0, 0.3 * s])), np.array([0.5 * s, 0.1 * np.sin(s), 0.0]))


class SyntheticSource:
    """Odometry at `odom_hz` and 8x8 frames at `frame_hz` for `seconds`, merged in time order."""

    def __init__(self, seconds: float = 2.0, odom_hz: float = 200.0, frame_hz: float = 10.0) -> None:
        self.name, self.stats = "synthetic", StreamStats()
        self.msgs: list[Message] = []
        for i in range(int(seconds * odom_hz)):
            t = int(i * 1e9 / odom_hz) + 1 * MS
            self.msgs.append(Odometry(t, T_odom_base_at(t)))
        K = np.array([[10.0, 0, 4], [0, 10.0, 4], [0, 0, 1]])
        for i in range(int(seconds * frame_hz)):
            t = int(i * 1e9 / frame_hz) + 2 * MS
            self.msgs.append(RgbdFrame(t, np.zeros((8, 8, 3), np.uint8), None, K, index=i))
        self.msgs.sort(key=lambda m: m.t_ns)

    def __iter__(self) -> Any:
        return iter(self.msgs)

    def frame_count(self) -> int:
        return sum(isinstance(m, RgbdFrame) for m in self.msgs)

    def n_odometry(self) -> int:
        return sum(isinstance(m, Odometry) for m in self.msgs)


@dataclass(frozen=True)
class Result:
    """A VLoc result as the service takes it (`runtime.service.core.VlocOutcome`)."""

    t_ns: int
    accepted: bool
    reason: str
    T_map_camera: np.ndarray | None = None
    covariance: np.ndarray | None = None
    timings_ms: dict[str, float] = field(default_factory=dict)
    provisional: None = None
    tracking_state: str = ""


class FakeVloc:
    """Returns the true camera pose (accepted) except for frames in `reject`; optional delay/failure."""

    def __init__(self, delay_s: float = 0.0, reject_after_ns: int | None = None, fail_at: int | None = None) -> None:
        self.delay_s, self.reject_after_ns, self.fail_at = delay_s, reject_after_ns, fail_at
        self.seen: list[int] = []
        self.priors: list[np.ndarray | None] = []

    def __call__(self, frame: RgbdFrame, prior: np.ndarray | None) -> Result:
        self.seen.append(frame.index)
        self.priors.append(prior)
        if self.fail_at is not None and frame.index == self.fail_at:
            raise RuntimeError(f"model crashed on frame {frame.index}")
        if self.delay_s:
            time.sleep(self.delay_s)
        if self.reject_after_ns is not None and frame.t_ns > self.reject_after_ns:
            return Result(frame.t_ns, False, "too few inliers")
        T = T_MAP_ODOM_TRUE @ T_odom_base_at(frame.t_ns) @ T_BASE_CAMERA_OPTICAL
        return Result(frame.t_ns, True, "ok", T, np.eye(6) * 1e-4)


@dataclass
class Fused:
    t_ns: int
    T_map_base: np.ndarray
    T_map_odom: np.ndarray
    covariance: np.ndarray
    initialised: bool


@dataclass
class Update:
    accepted: bool
    reason: str = "ok"
    mahalanobis2: float = 0.0


@dataclass
class FakeFusion:
    """T_map_odom from the latest VLoc fix (with the odometry at the fix time); no smoothing."""

    T_map_odom: np.ndarray | None = None
    odom: dict[int, np.ndarray] = field(default_factory=dict)
    last: Odometry | None = None

    def add_odometry(self, o: Odometry) -> Fused | None:
        self.last = o
        self.odom[o.t_ns] = o.T_odom_base
        if self.T_map_odom is None:  # as the GTSAM fusion: no pose before its first fix
            return None
        return Fused(o.t_ns, self.T_map_odom @ o.T_odom_base, self.T_map_odom, np.eye(6) * 0.01, True)

    def add_vloc(self, r: Result) -> Update:
        assert r.T_map_camera is not None
        T_map_base = r.T_map_camera @ invert(T_BASE_CAMERA_OPTICAL)
        self.T_map_odom = T_map_base @ invert(T_odom_base_at(r.t_ns))
        return Update(True)


class FakePublisher:
    """Records what the service hands on; a pose's flag: its covariance carries the LOST variance."""

    def __init__(self, lost_variance: float = 1.0e4) -> None:
        self.lost_variance = lost_variance
        self.poses: list[tuple[int, np.ndarray, bool]] = []
        self.m2o: list[tuple[int, np.ndarray]] = []
        self.vloc: list[int] = []
        self.status: list[dict[str, Any]] = []

    def publish_pose(self, t_ns: int, T: Any, cov: Any) -> None:
        flagged = cov is not None and bool(np.all(np.diag(np.asarray(cov)) >= self.lost_variance))
        self.poses.append((t_ns, np.asarray(T), flagged))

    def publish_map_to_odom(self, t_ns: int, T: Any) -> None:
        self.m2o.append((t_ns, np.asarray(T)))

    def publish_vloc(self, t_ns: int, T: Any, cov: Any) -> None:
        self.vloc.append(t_ns)

    def publish_status(self, status: dict[str, Any]) -> None:
        self.status.append(status)


class FusionLike(Protocol):
    def add_odometry(self, o: Odometry) -> Any: ...

    def add_vloc(self, r: Any) -> Any: ...


def make_service(source: Iterable[Any], vloc: Any, fusion: FusionLike, publisher: Any = None,
                 params: RuntimeConfig | None = None, *, rate: float = 1.0,
                 covariance_to_ros: Any = None, on_fused: Any = None, odometry_receiver: Any = None,
                 T_base_camera: np.ndarray = T_BASE_CAMERA_OPTICAL, configure_thread_counts: bool = True) -> Service:
    """A `Service` around a fake fusion (`add_odometry(odom)`, `add_vloc(result)`), its core built here."""
    core = LocalizationCore(FusionPort(fusion.add_odometry, fusion.add_vloc, covariance_to_ros=covariance_to_ros),
                            params, T_base_camera=T_base_camera, on_fused=on_fused)
    return Service(source, vloc, core, ServicePorts(publisher, odometry_receiver), rate=rate,
                   configure_thread_counts=configure_thread_counts)
