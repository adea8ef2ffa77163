"""Batch refinement (PS-Opt): beats the causal filter and survives outliers."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from litevloc.base.geometry import interpolate_pose_at
from litevloc.base.params.drift import T_BASE_CAMERA_OPTICAL, DriftParams
from litevloc.base.params.fusion import FusionParams
from litevloc.experiments.fusion_sim import simulate_vloc, synthetic_trajectory
from litevloc.pipelines.evaluation.trajectory import ate
from litevloc.pipelines.fusion.batch import refine_session
from litevloc.pipelines.odometry_drift import simulate_odometry

T_BC = T_BASE_CAMERA_OPTICAL


def test_batch_refine_is_accurate_and_robust() -> None:
    gt_t, T_wb = synthetic_trajectory(60.0, 30.0, seed=5)
    ot, oT = simulate_odometry(gt_t, T_wb, 100.0, DriftParams(), seed=1)
    gt_o = np.stack([interpolate_pose_at(int(t), gt_t, T_wb) for t in ot])
    p = FusionParams()
    odo_ate = ate(oT, gt_o).rmse
    res = {}
    for name, outl, params in (
        ("clean", 0.0, p),
        ("robust", 0.1, p),
        ("naive", 0.1, dataclasses.replace(p, robust_kernel="none", gate_chi2=0.0)),
    ):
        vl = simulate_vloc(gt_t, T_wb @ T_BC, 1.0, outlier_ratio=outl, seed=11)
        r = refine_session(ot, oT, vl.t_capture_ns, vl.T_map_camera, None, params, T_BC)
        assert len(r.times_ns) == len(ot)  # a pose at every odometry time
        res[name] = ate(r.T_map_base, gt_o, align=False).rmse
        if name == "robust":
            assert r.info.priors_gated >= int(vl.outlier.sum()) - 1
    assert res["clean"] < 0.5 * odo_ate
    assert res["robust"] <= 1.5 * res["clean"]
    assert res["naive"] >= 2.0 * res["robust"]
    T = refine_session(ot, oT, vl.t_capture_ns, vl.T_map_camera, None, p, T_BC).T_map_base
    assert T.shape == (len(ot), 4, 4)


def test_batch_refine_rejects_bad_input() -> None:
    with pytest.raises(ValueError, match="inside the odometry time span"):
        refine_session(
            np.array([0, 10]),
            np.stack([np.eye(4)] * 2),
            np.array([99]),
            np.eye(4)[None],
            None,
            FusionParams(),
            np.eye(4),
        )
    with pytest.raises(ValueError, match="strictly increasing"):
        refine_session(
            np.array([0, 0]),
            np.stack([np.eye(4)] * 2),
            np.array([0]),
            np.eye(4)[None],
            None,
            FusionParams(),
            np.eye(4),
        )
