"""The localization core on its own: typed outputs from odometry and VLoc steps, one tracking
state machine with reasons, the map->odom throttle; and the same outputs in every service mode."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from litevloc.base.params.drift import T_BASE_CAMERA_OPTICAL
from litevloc.config.schema import RuntimeConfig
from litevloc.hw.messages import Odometry
from litevloc.runtime.service.core import FusionPort, LocalizationCore, PoseOut, VlocOut
from tests.runtime.fakes import (
    MS,
    T_MAP_ODOM_TRUE,
    FakeFusion,
    FakePublisher,
    FakeVloc,
    Result,
    SyntheticSource,
    T_odom_base_at,
    make_service,
)


def fix(t_ns: int, state: str = "") -> Result:
    T = T_MAP_ODOM_TRUE @ T_odom_base_at(t_ns) @ T_BASE_CAMERA_OPTICAL
    return Result(t_ns, True, "ok", T, np.eye(6) * 1e-4, tracking_state=state)


def make_core(**params: object) -> tuple[LocalizationCore, FakeFusion]:
    fusion = FakeFusion()
    core = LocalizationCore(FusionPort(fusion.add_odometry, fusion.add_vloc),
                            RuntimeConfig(**params))  # type: ignore[arg-type]
    return core, fusion


def test_steps_return_typed_outputs_and_throttle_map_to_odom() -> None:
    core, _ = make_core(map_to_odom_period_s=0.1)
    assert core.odometry(Odometry(1 * MS, T_odom_base_at(1 * MS)), 0) == []  # not initialised: nothing to publish
    assert core.tracking_state() == ("INIT", ["waiting for the first accepted VLoc fix"])
    assert core.prior(1 * MS) is None
    outs = core.vloc_result(fix(2 * MS))
    assert len(outs) == 1 and isinstance(outs[0], VlocOut) and outs[0].t_ns == 2 * MS
    kinds = []
    for k in range(1, 41):  # 200 Hz for 0.2 s
        t = 1 * MS + k * 5 * MS
        out = core.odometry(Odometry(t, T_odom_base_at(t)), t_in_ns=k)
        assert isinstance(out[0], PoseOut) and out[0].t_in_ns == k and not out[0].lost
        assert np.allclose(out[0].T_map_base, T_MAP_ODOM_TRUE @ T_odom_base_at(t))
        kinds.append([type(o).__name__ for o in out])
    m2o = [i for i, k in enumerate(kinds) if "MapToOdomOut" in k]
    assert m2o == [0, 20]  # right after the fix, then every 0.1 s of sensor time
    c = core.counters
    assert c["odometry_fused"] == 41 and c["vloc_accepted"] == c["fusion_accepted"] == 1


def test_lost_by_fix_age_and_by_the_localizers_own_state() -> None:
    core, _ = make_core(lost_after_s=0.5)
    core.odometry(Odometry(1 * MS, T_odom_base_at(1 * MS)), 0)
    core.vloc_result(fix(2 * MS, state="TRACKING"))
    out = core.odometry(Odometry(10 * MS, T_odom_base_at(10 * MS)), 0)
    assert core.tracking_state() == ("TRACKING", []) and not out[0].lost
    # the localizer's state machine went LOST (reported with its result): published poses say so
    rejected = Result(20 * MS, False, "too few inliers", tracking_state="LOST")
    assert core.vloc_result(rejected) == []
    out = core.odometry(Odometry(30 * MS, T_odom_base_at(30 * MS)), 0)
    state, reasons = core.tracking_state()
    assert state == "LOST" and reasons == ["localizer state machine is LOST"] and out[0].lost
    assert core.report()["vloc_state"] == "LOST" and core.counters["vloc_rejected"] == 1
    # a new fix with the localizer tracking again; then no fix for longer than lost_after_s
    core.vloc_result(fix(40 * MS, state="TRACKING"))
    core.odometry(Odometry(45 * MS, T_odom_base_at(45 * MS)), 0)
    assert core.tracking_state()[0] == "TRACKING"
    out = core.odometry(Odometry(700 * MS, T_odom_base_at(700 * MS)), 0)
    state, reasons = core.tracking_state()
    assert state == "LOST" and reasons[0].startswith("no VLoc fix accepted for 0.7 s") and out[0].lost


def test_fusion_refusals_are_counted_and_named() -> None:
    core, _ = make_core()

    @dataclasses.dataclass
    class Refusal:
        accepted: bool = False
        reason: str = "gated"

    core.odometry(Odometry(1 * MS, T_odom_base_at(1 * MS)), 0)
    core.vloc_result(fix(2 * MS))
    core.odometry(Odometry(2 * MS + 1, T_odom_base_at(2 * MS + 1)), 0)  # fusion's first pose
    core.fusion = dataclasses.replace(core.fusion, on_vloc=lambda r: Refusal())
    assert core.vloc_result(fix(3 * MS)) == []
    core.fusion = dataclasses.replace(core.fusion, on_odometry=lambda o: None)  # fusion refuses an odometry message
    assert core.odometry(Odometry(4 * MS, T_odom_base_at(4 * MS)), 0) == []
    rep = core.report()
    assert rep["counters"]["fusion_rejected"] == 1 and rep["last_fusion_reason"] == "gated"
    assert rep["counters"]["odometry_rejected"] == 1
    assert any("fusion rejected 1 odometry message" in r for r in rep["reasons"])


def _published(mode: str) -> tuple[list[tuple[int, bool]], list[int], list[int]]:
    pub = FakePublisher()
    fusion = FakeFusion()
    svc = make_service(SyntheticSource(seconds=1.0), FakeVloc(reject_after_ns=600 * MS), fusion, pub,
                       RuntimeConfig(mode=mode, lost_after_s=0.2, map_to_odom_period_s=0.05),
                       rate=0.0)
    res = svc.run(timeout_s=20)
    assert res.ok, res.reason
    return [(t, lost) for t, _, lost in pub.poses], [t for t, _ in pub.m2o], pub.vloc


@pytest.mark.timeout(60)
def test_the_same_inputs_give_the_same_outputs_in_every_mode() -> None:
    """Sequential (inline) and deterministic (threads + queues) publish exactly the same
    poses, LOST flags, map->odom corrections and VLoc fixes. (Realtime mode drops frames by
    design, so its outputs depend on timing.)"""
    seq = _published("sequential")
    det = _published("deterministic")
    assert seq == det
    poses, m2o, vloc = seq
    assert any(lost for _, lost in poses) and not poses[0][1]  # the run goes LOST after 0.6 s + 0.2 s
    assert len(m2o) > 10 and len(vloc) == 6


def test_lost_policy_is_decided_here_flagged_or_withheld() -> None:
    """The core hands the publisher the final covariance (flag) or nothing (withhold); the
    publisher only serialises it."""
    for policy in ("flag", "withhold"):
        core, _ = make_core(lost_after_s=0.5, lost_policy=policy, lost_variance=5e3)
        core.odometry(Odometry(1 * MS, T_odom_base_at(1 * MS)), 0)
        core.vloc_result(fix(2 * MS, state="TRACKING"))
        out = core.odometry(Odometry(10 * MS, T_odom_base_at(10 * MS)), 0)
        assert not out[0].lost and np.allclose(np.diag(out[0].covariance), 0.01)  # the fake's, unchanged
        out = core.odometry(Odometry(700 * MS, T_odom_base_at(700 * MS)), 0)  # no fix for 0.7 s: LOST
        if policy == "flag":
            assert isinstance(out[0], PoseOut) and out[0].lost  # (map->odom goes on, its last good value)
            assert np.allclose(np.diag(out[0].covariance), 5e3) and core.poses_flagged == 1
        else:
            assert out == [] and core.counters["poses_withheld"] == 1 and core.poses_flagged == 0  # no map->odom


def test_the_vloc_thread_reads_one_frozen_snapshot_per_fusion_step() -> None:
    """Each fusion step replaces the snapshot whole; one read by the VLoc thread keeps that
    step's pose, covariance and fix time together, and the fused pose's arrays cannot change."""
    import pytest

    from litevloc.base.params.fusion import FusionParams
    from litevloc.pipelines.fusion.online import OnlineFusion
    from litevloc.runtime.service.fusion_port import fusion_port

    core = LocalizationCore(fusion_port(OnlineFusion(FusionParams(init_votes=1), T_BASE_CAMERA_OPTICAL)),
                            RuntimeConfig())
    core.odometry(Odometry(1 * MS, T_odom_base_at(1 * MS)), 0)
    core.vloc_result(fix(1 * MS))
    core.odometry(Odometry(6 * MS, T_odom_base_at(6 * MS)), 0)
    before = core.snapshot
    assert before.fused is not None and before.fused.initialised and before.last_fix_ns == 1 * MS
    core.odometry(Odometry(11 * MS, T_odom_base_at(11 * MS)), 0)
    after = core.snapshot
    assert after is not before and before.sensor_now_ns == 6 * MS and after.sensor_now_ns == 11 * MS
    assert before.fused is not None and before.fused.t_ns == 6 * MS  # the old one is as it was
    assert after.fused is not None and after.fused.t_ns == 11 * MS and after.last_fix_ns == 1 * MS
    with pytest.raises(dataclasses.FrozenInstanceError):
        after.fused = None  # type: ignore[misc]
    assert after.fused is not None and after.covariance is not None
    with pytest.raises(ValueError, match="read-only"):
        after.fused.T_map_base[0, 3] = 1.0
    with pytest.raises(ValueError, match="read-only"):
        after.covariance[0, 0] = 1.0
