"""Fault scenarios on the real service + GTSAM fusion, cheap enough for unit tests.

The robot drives a simulated office pass (`sim` trajectory: ground truth and drift
odometry at 200 Hz; nothing is rendered). Frames are tiny placeholders at `frame_hz`;
VLoc is an *oracle* that returns the true camera pose with a little noise (the real
localizer is exercised elsewhere; here the question is what the runtime and fusion do
when inputs misbehave), and that rejects a frame whose depth has no valid pixel, as the
real one does ("too few matches with depth"). `runtime.service.faults.FaultInjector` injects
the faults. Used by tests/runtime/test_faults.py and bench/faults.py.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any

import numpy as np

from litevloc.base.geometry import make_T, so3_exp
from litevloc.config import load_config
from litevloc.hw.messages import GroundTruthPose, Message, Odometry, RgbdFrame
from litevloc.pipelines.fusion.online import OnlineFusion
from litevloc.runtime.service.core import LocalizationCore
from litevloc.runtime.service.faults import FaultInjector
from litevloc.runtime.service.fusion_port import fusion_port
from litevloc.runtime.service.shell import Service


@dataclass(frozen=True)
class OracleResult:
    t_ns: int
    accepted: bool
    reason: str
    T_map_camera: np.ndarray | None = None
    covariance: np.ndarray | None = None
    timings_ms: dict[str, float] = field(default_factory=dict)
    provisional: None = None
    tracking_state: str = ""


@lru_cache(maxsize=4)
def sim_pass(seconds: float, seed: int = 1) -> tuple[np.ndarray, np.ndarray, np.ndarray, Any]:
    """(t_ns, T_odom_base, T_world_camera at t_ns, sim) of the office map pass, no rendering."""
    from litevloc.sim.source import SimSequenceSource
    from litevloc.sim.world import load_world

    src = SimSequenceSource(load_world("office"), "map", seed, duration=seconds)
    t = src.run.t_ns
    cams = np.stack([src._cam_pose(int(x)) for x in t])
    return t, src.run.T_odom_base, cams, src


def messages(seconds: float, frame_hz: float = 5.0, seed: int = 1) -> Iterator[Message]:
    """Odometry (every sample), placeholder RGB-D frames and ground truth at `frame_hz`."""
    t, T_odom, cams, _src = sim_pass(seconds, seed)
    K = np.array([[40.0, 0, 32], [0, 40.0, 24], [0, 0, 1]])
    step = max(1, round(1e9 / frame_hz / float(np.median(np.diff(t)))))
    color = np.zeros((48, 64, 3), np.uint8)
    depth = np.full((48, 64), 2.0, np.float32)
    for k in range(len(t)):
        yield Odometry(int(t[k]), T_odom[k].copy())
        if k % step == 0:
            yield RgbdFrame(int(t[k]), color, depth, K, index=k // step)
            yield GroundTruthPose(int(t[k]), cams[k], index=k // step)


class OracleVloc:
    """True camera pose + noise (1 cm, 0.3 deg); rejects frames without valid depth."""

    def __init__(self, seconds: float, seed: int = 1) -> None:
        t, _, cams, _ = sim_pass(seconds, seed)
        self.poses = {int(a): b for a, b in zip(t, cams, strict=True)}
        self.rng = np.random.default_rng(seed)
        self.cov = np.diag([1e-4, 1e-4, 1e-4, 3e-5, 3e-5, 3e-5])

    def __call__(self, frame: RgbdFrame, prior: Any) -> OracleResult:
        if frame.depth is None or not np.isfinite(frame.depth).any():
            return OracleResult(frame.t_ns, False, "too few matches with depth (0)")
        T = self.poses[frame.t_ns] @ make_T(so3_exp(self.rng.normal(0, 0.005, 3)), self.rng.normal(0, 0.01, 3))
        return OracleResult(frame.t_ns, True, "ok", T, self.cov)


@dataclass
class ScenarioResult:
    ok: bool
    reason: str
    status: dict[str, Any]
    fusion_stats: dict[str, Any]
    changed: dict[str, int]
    t_rel: np.ndarray  # s since the first message, per fused pose
    err_m: np.ndarray  # fused camera position error there (m)
    states: list[tuple[float, str, list[str]]] = field(default_factory=list)  # (rel s, state, reasons)

    def error_between(self, a: float, b: float) -> np.ndarray:
        return self.err_m[(self.t_rel >= a) & (self.t_rel < b)]

    def states_between(self, a: float, b: float) -> set[str]:
        return {s for t, s, _ in self.states if a <= t < b}

    def reasons_between(self, a: float, b: float) -> list[str]:
        return [r for t, _, rs in self.states if a <= t < b for r in rs]


def run_scenario(faults: list[str], seconds: float = 30.0, frame_hz: float = 5.0, lost_after_s: float = 3.0,
                 seed: int = 1, mode: str = "deterministic", rate: float = 0.0) -> ScenarioResult:
    cfg = load_config("default", [f"runtime.mode={mode}", f"runtime.lost_after_s={lost_after_s}"])
    T_bc = cfg.fusion.T_base_camera()
    fusion = OnlineFusion(cfg.fusion.params, T_bc)
    inj = FaultInjector(faults)
    t_all, _, cams, _ = sim_pass(seconds, seed)
    gt = {int(a): b for a, b in zip(t_all, cams, strict=True)}  # true camera pose at every odometry stamp
    errs: list[tuple[int, float]] = []
    states: list[tuple[float, str, list[str]]] = []
    holder: dict[str, Service] = {}
    next_status = [0]

    def on_fused(f: Any) -> None:
        if not f.initialised:
            return
        g = gt.get(int(f.t_ns))
        if g is not None:
            errs.append((int(f.t_ns), float(np.linalg.norm((f.T_map_base @ T_bc)[:3, 3] - g[:3, 3]))))
        if f.t_ns >= next_status[0]:  # status as the service reports it, every 0.5 s of sensor time
            next_status[0] = int(f.t_ns) + 500_000_000
            st = holder["svc"].status()
            states.append((inj.rel_s(int(f.t_ns)), st["state"], list(st["reasons"])))

    core = LocalizationCore(fusion_port(fusion), cfg.runtime, T_base_camera=T_bc, on_fused=on_fused)
    svc = Service(messages(seconds, frame_hz, seed), OracleVloc(seconds, seed), core, rate=rate,
                  configure_thread_counts=False)
    holder["svc"] = svc
    inj.apply(svc)
    res = svc.run(timeout_s=120)
    e = np.array(errs, dtype=np.float64).reshape(-1, 2)
    return ScenarioResult(res.ok, res.reason, res.status, fusion.stats(), dict(inj.counts),
                          np.array([inj.rel_s(int(x)) for x in e[:, 0]]), e[:, 1], states)


def summary_row(name: str, r: ScenarioResult, start: float, end: float, recover_s: float) -> dict[str, Any]:
    """Errors before / during / in the `recover_s` after / after that, and the states seen."""

    def stat(a: np.ndarray) -> float:
        return float(np.max(a)) if a.size else float("nan")

    return {
        "fault": name, "ok": r.ok, "reason": r.reason, "changed": r.changed,
        "max_err_before_m": stat(r.error_between(0.0, start)),
        "max_err_during_m": stat(r.error_between(start, end)),
        "max_err_recovery_m": stat(r.error_between(end, end + recover_s)),
        "max_err_after_m": stat(r.error_between(end + recover_s, 1e9)),
        "states_during": sorted(r.states_between(start, end + 0.5)),
        "states_after": sorted(r.states_between(end + recover_s, 1e9)),
        "reasons_during": sorted(set(r.reasons_between(start, end + 0.5)))[:4],
        "odometry_rejected": r.fusion_stats["odometry_rejected"],
        "vloc_by_reason": r.fusion_stats["vloc_by_reason"],
        "counters": {k: r.status["counters"][k] for k in ("odometry_in", "odometry_fused", "frames_in",
                                                            "vloc_accepted", "vloc_rejected", "fusion_accepted",
                                                            "fusion_rejected")},
    }


__all__ = ["OracleVloc", "ScenarioResult", "messages", "run_scenario", "summary_row"]
