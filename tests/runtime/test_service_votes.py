"""Provisional (single-keyframe) GL poses reach the real GTSAM fusion as initialisation votes."""

from __future__ import annotations

import numpy as np
import pytest

from litevloc.base.params.drift import T_BASE_CAMERA_OPTICAL
from litevloc.base.params.fusion import FusionParams
from litevloc.config.schema import RuntimeConfig
from litevloc.hw.messages import RgbdFrame
from litevloc.pipelines.fusion.online import OnlineFusion
from litevloc.pipelines.localization.results import LocalizationResult, ProvisionalPose
from litevloc.runtime.service.core import LocalizationCore
from litevloc.runtime.service.fusion_port import fusion_port
from litevloc.runtime.service.shell import Service, ServicePorts
from tests.runtime.fakes import T_MAP_ODOM_TRUE, FakePublisher, SyntheticSource, T_odom_base_at


class VotingVloc:
    """Never accepts; returns the true pose as a provisional one (a place one keyframe sees)."""

    def __init__(self) -> None:
        self.priors: list[np.ndarray | None] = []

    def __call__(self, frame: RgbdFrame, prior: np.ndarray | None) -> LocalizationResult:
        self.priors.append(prior)
        T = T_MAP_ODOM_TRUE @ T_odom_base_at(frame.t_ns) @ T_BASE_CAMERA_OPTICAL
        prov = ProvisionalPose(T, np.eye(6) * 1e-4, node=3, n_inliers=90)
        return LocalizationResult(frame.t_ns, "global", False, "not localized: one keyframe only", provisional=prov)


@pytest.mark.timeout(30)
def test_provisional_poses_initialise_fusion_but_are_not_fixes() -> None:
    src = SyntheticSource(seconds=2.0)
    fusion = OnlineFusion(FusionParams(init_votes=2), T_BASE_CAMERA_OPTICAL)
    core = LocalizationCore(fusion_port(fusion), RuntimeConfig(mode="deterministic", lost_after_s=60.0))
    vloc, pub = VotingVloc(), FakePublisher()
    svc = Service(src, vloc, core, ServicePorts(pub))
    res = svc.run(timeout_s=20)
    assert res.ok, res.reason
    c = res.status["counters"]
    n = src.frame_count()
    assert c["vloc_votes"] == c["vloc_rejected"] == n and c["vloc_accepted"] == 0 and c["vloc_published"] == 0
    assert c["fusion_initialised_by_votes"] == 1  # two agreeing votes initialise; later ones are ignored
    assert fusion.stats()["vloc_by_reason"]["vote_ignored"] == n - 2
    assert vloc.priors[0] is None and vloc.priors[-1] is not None  # the localizer now gets a prior
    assert pub.poses and pub.m2o
    t, T, _ = pub.poses[-1]
    err = np.linalg.norm(T[:3, 3] - (T_MAP_ODOM_TRUE @ T_odom_base_at(t))[:3, 3])
    assert err < 0.02
