"""`litevloc/diagnostics`: DiagnosticArray built from the status, levels from config, on the wire."""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from litevloc.base.loader import ConfigError, from_mapping
from litevloc.config.schema import DiagnosticsConfig, LevelThresholds, LiteVLocConfig, RuntimeConfig, ZenohConfig
from litevloc.hw.messages import RgbdFrame
from litevloc.runtime.service.diagnostics import (
    ERROR,
    OK,
    WARN,
    DiagnosticsPublisher,
    VlocStageTimes,
    diagnostic_statuses,
)
from litevloc.runtime.transport.bus import Bus, LiteVLocPublisher
from tests.runtime.fakes import FakeFusion, FakeVloc, SyntheticSource, make_service
from tests.runtime.zenoh_helpers import free_port


def _status(fusion_p99: float = 1.0, state: str = "TRACKING", calls: int = 10, accepted: int = 9,
            uptime: float = 10.0, odo_depth: int = 0, overflows: int = 0) -> dict[str, Any]:
    lat = {"count": 50, "median_ms": fusion_p99 / 2, "p99_ms": fusion_p99, "last_ms": 0.4}
    return {
        "uptime_s": uptime, "state": state,
        "reasons": ["no VLoc fix accepted for 12.0 s (> 10)"] if state == "LOST" else [],
        "counters": {"vloc_calls": calls, "vloc_accepted": accepted},
        "queues": {"frames": {"kind": "latest", "depth": 1, "capacity": 1, "drops": 7, "overflows": 0},
                   "odometry": {"kind": "fifo", "depth": odo_depth, "capacity": 100, "drops": 0,
                                "overflows": overflows, "high_water": odo_depth}},
        "stages": {"fusion": {"latency": {"odometry": lat}}, "publisher": {"latency": {"outbox": lat}}},
        "vloc_stages": {"extract": {"count": 3, "median_ms": 90.0, "p99_ms": 120.0, "last_ms": 95.0}},
    }


def _by_name(entries: list) -> dict[str, tuple]:
    return {e[1]: e for e in entries}


def test_levels_follow_configurable_thresholds() -> None:
    cfg = DiagnosticsConfig()
    e = _by_name(diagnostic_statuses(_status(), None, cfg, "office@abc", 40))
    assert set(e) >= {f"litevloc/stage/{s}" for s in ("extract", "vpr", "match", "pnp", "fusion", "publish")}
    assert e["litevloc/stage/fusion"][0] == OK and e["litevloc/tracking"][0] == OK
    assert dict(e["litevloc/stage/extract"][4])["last_ms"] == "95.000"
    assert e["litevloc/stage/vpr"][2] == "no samples yet"
    assert e["litevloc/queue/frames"][0] == OK  # latest-value drops are by design
    assert dict(e["litevloc/map"][4]) == {"map_id": "office@abc", "nodes": "40"}
    # the same snapshot under tighter thresholds: WARN, then ERROR
    warn = dataclasses.replace(cfg, fusion_ms=LevelThresholds(0.5, 5.0))
    assert _by_name(diagnostic_statuses(_status(), None, warn))["litevloc/stage/fusion"][0] == WARN
    err = dataclasses.replace(cfg, fusion_ms=LevelThresholds(0.1, 0.9))
    assert _by_name(diagnostic_statuses(_status(), None, err))["litevloc/stage/fusion"][0] == ERROR
    # tracking, queues, VLoc rate / acceptance over the period (vs the previous snapshot)
    e = _by_name(diagnostic_statuses(_status(state="LOST", odo_depth=60), None, cfg))
    assert e["litevloc/tracking"][0] == ERROR and "no VLoc fix" in e["litevloc/tracking"][2]
    assert e["litevloc/queue/odometry"][0] == WARN
    assert _by_name(diagnostic_statuses(_status(overflows=2), None, cfg))["litevloc/queue/odometry"][0] == ERROR
    assert _by_name(diagnostic_statuses(_status(state="INIT"), None, cfg))["litevloc/tracking"][0] == WARN
    prev = {"counters": {"vloc_calls": 10, "vloc_accepted": 9}, "uptime_s": 10.0}
    v = _by_name(diagnostic_statuses(_status(calls=12, accepted=9, uptime=11.0), prev, cfg))["litevloc/vloc"]
    assert v[0] == ERROR and dict(v[4])["rate_hz"] == "2.000" and dict(v[4])["acceptance"] == "0.000"
    v = _by_name(diagnostic_statuses(_status(calls=12, accepted=12, uptime=11.0), prev, cfg))["litevloc/vloc"]
    assert v[0] == OK
    slow = dataclasses.replace(cfg, vloc_rate_hz=LevelThresholds(5.0, 1.0))
    assert _by_name(diagnostic_statuses(_status(calls=12, accepted=12, uptime=11.0), prev, slow))[
        "litevloc/vloc"][0] == WARN


def test_thresholds_are_validated_config() -> None:
    cfg = from_mapping(LiteVLocConfig, {"diagnostics": {"pnp_ms": {"warn": 5, "error": 9}, "period_s": 2}})
    assert cfg.diagnostics.pnp_ms == LevelThresholds(5.0, 9.0) and cfg.diagnostics.period_s == 2.0
    for bad in ({"pnp_ms": {"warn": 9, "error": 5}}, {"vloc_rate_hz": {"warn": 0.1, "error": 1}},
                {"period_s": 0}, {"no_such_key": 1}, {"pnp_ms": {"warn": 1e9}}):
        with pytest.raises(ConfigError, match="diagnostics"):
            from_mapping(LiteVLocConfig, {"diagnostics": bad})
    # one threshold of a pair overridden: the other keeps its default
    part = from_mapping(LiteVLocConfig, {"diagnostics": {"pnp_ms": {"warn": 1}}})
    assert part.diagnostics.pnp_ms.warn == 1.0
    assert part.diagnostics.pnp_ms.error == LiteVLocConfig().diagnostics.pnp_ms.error


def test_vloc_stage_times_window() -> None:
    t = VlocStageTimes(4)
    for i in range(6):
        t.add({"extract": float(i), "match": 10.0 + i, "total": 99.0})
    t.add(None)
    s = t.summary()
    assert s["extract"]["count"] == 4 and s["extract"]["last_ms"] == 5.0 and s["match"]["median_ms"] == 13.5
    assert s["pnp"]["count"] == 0


@dataclass(frozen=True)
class _TimedResult:
    t_ns: int
    accepted: bool
    reason: str
    T_map_camera: Any = None
    covariance: Any = None
    timings_ms: dict[str, float] = field(default_factory=dict)
    provisional: None = None
    tracking_state: str = ""


def _timed(vloc: FakeVloc):
    def fn(frame: RgbdFrame, prior: Any) -> _TimedResult:
        r = vloc(frame, prior)
        return _TimedResult(r.t_ns, r.accepted, r.reason, r.T_map_camera, r.covariance,
                            {"extract": 80.0 + frame.index, "vpr": 20.0, "match": 150.0, "pnp": 1.5, "total": 260.0})
    return fn


@pytest.mark.timeout(60)
def test_diagnostics_on_the_wire_decoded_by_independent_readers(tmp_path: Path) -> None:
    """The service's status tick publishes DiagnosticArray CDR on Zenoh; rosbags (a fresh
    typestore) and mcap_ros2's dynamic decoder (from the .msg text) both read it."""
    from mcap_ros2._dynamic import generate_dynamic
    from rosbags.typesys import Stores, get_typestore

    from litevloc.hw.ros_msgs import DIAGNOSTIC_ARRAY, msgdef

    ep = f"tcp/127.0.0.1:{free_port()}"
    payloads: list[bytes] = []
    with Bus(ZenohConfig(listen=(ep,))) as bus:
        pub = LiteVLocPublisher(bus, diagnostics=DiagnosticsPublisher(
            DiagnosticsConfig(period_s=0.25, extract_ms=LevelThresholds(85.0, 1000.0)), "office@0123456789ab", 12))
        with Bus(ZenohConfig(listen=(), connect=(ep,))) as sub_bus:
            sub = sub_bus.subscribe("litevloc/diagnostics", lambda s: payloads.append(bytes(s.payload.to_bytes())))
            assert pub.pubs["diagnostics"].wait_for_subscribers(5.0)
            fusion = FakeFusion()
            svc = make_service(SyntheticSource(seconds=1.5, odom_hz=100, frame_hz=10), _timed(FakeVloc()), fusion,
                               pub, RuntimeConfig(mode="realtime", status_period_s=0.25), rate=1.0,
                               configure_thread_counts=False)
            res = svc.run(timeout_s=20)
            assert res.ok, res.reason
            pub.publish_status(svc.status())  # a last one after the end (rate-limited like the others)
            time.sleep(0.3)
            sub.undeclare()
    assert len(payloads) >= 3, f"only {len(payloads)} diagnostics messages"
    ts = get_typestore(Stores.ROS2_HUMBLE)
    msgs = [ts.deserialize_cdr(p, DIAGNOSTIC_ARRAY) for p in payloads]
    last = {s.name: s for s in msgs[-1].status}
    ext = last["litevloc/stage/extract"]
    kv = {v.key: v.value for v in ext.values}
    assert int(kv["samples"]) >= 10 and float(kv["median_ms"]) > 85.0
    assert ext.level == WARN  # frame index > 5 -> extract > 85 ms: the configured WARN threshold
    assert last["litevloc/stage/fusion"].level == OK and int({v.key: v.value for v in
                                                               last["litevloc/stage/fusion"].values}["samples"]) > 50
    assert last["litevloc/map"].message == "office@0123456789ab"
    assert last["litevloc/tracking"].level in (OK, ERROR)  # TRACKING while running; the end may be LOST
    assert any({s.name: s for s in m.status}["litevloc/tracking"].level == OK for m in msgs)
    assert msgs[-1].header.stamp.sec > 1_600_000_000  # wall-clock stamp
    decode = generate_dynamic(DIAGNOSTIC_ARRAY.replace("/msg/", "/"), msgdef(DIAGNOSTIC_ARRAY))[
        DIAGNOSTIC_ARRAY.replace("/msg/", "/")]
    other = decode(payloads[-1])
    assert [s.name for s in other.status] == [s.name for s in msgs[-1].status]
    assert [s.level for s in other.status] == [s.level for s in msgs[-1].status]
    np.testing.assert_array_equal([len(s.values) for s in other.status], [len(s.values) for s in msgs[-1].status])
