"""A visual edge over a corridor's floor whose target keypoints sit off the source's surface
points (as a detector's do on a foreshortened texture): aligned, the edge measures the motion;
unaligned, it measures it long (issue 41, `bench/vo_bias.py`)."""

from __future__ import annotations

import dataclasses

import numpy as np

from litevloc.base.geometry import backproject_pixels, transform_points
from litevloc.config import load_config
from litevloc.pipelines.depth_lookup import depth_at
from litevloc.pipelines.slam.frontend import FrontEnd
from litevloc.pipelines.slam.types import FrameImages, Keyframe, SlamModels
from litevloc.pipelines.topomap.types import NodeFeatures
from tests.pipelines import floor_views
from tests.pipelines.floor_views import H, K, W


def _no_model(*_: object) -> object:
    raise AssertionError("guided matching only: no model runs")


def _front_end(align: bool) -> FrontEnd:
    cfg = load_config("default")
    # a floor alone is one plane: AP3P's minimal sets are degenerate there, SQPnP's are not
    visual = dataclasses.replace(cfg.slam.visual, align=dataclasses.replace(cfg.slam.visual.align, enabled=align),
                                 pnp=dataclasses.replace(cfg.slam.visual.pnp, method="sqpnp"))
    slam = dataclasses.replace(cfg.slam, visual=visual)
    models = SlamModels(_no_model, _no_model, _no_model, _no_model)
    return FrontEnd(slam, cfg.mapping, cfg.localization, models, np.eye(4))


def _keyframe(fe: FrontEnd, kid: int, uv: np.ndarray, desc: np.ndarray, color: np.ndarray,
              depth: np.ndarray) -> Keyframe:
    z = depth_at(depth, uv, fe.mapping.depth)
    pts = np.full((len(uv), 3), np.nan)
    ok = np.isfinite(z)
    pts[ok] = backproject_pixels(K, uv[ok], z[ok].astype(np.float64))
    feats = NodeFeatures(uv.astype(np.float32), desc, np.ones(len(uv), np.float32), (W, H), z)
    return Keyframe(id=kid, index=kid, t_ns=0, K=K, size=(W, H), features=feats, points=pts,
                    vpr=np.zeros(1, np.float32), jpeg=b"", cloud=np.zeros((0, 3), np.float32), odom=None,
                    T_init=np.eye(4), chain=0, view=fe._view(FrameImages(color, depth.astype(np.float32)), K))


def test_aligned_edge_measures_the_motion_the_detector_would_stretch() -> None:
    pair = floor_views.floor_pair()
    T_t_s = pair["T_t_s"]
    uv_s = floor_views.keypoints(pair["ds"], 200, 5)
    z = depth_at(pair["ds"], uv_s).astype(np.float64)
    X = transform_points(T_t_s, backproject_pixels(K, uv_s, z))
    uv_true = (K @ X.T).T
    uv_true = uv_true[:, :2] / uv_true[:, 2:3]
    # the target's detector: 0.4 px toward the far side of each blob (up the image), noise 0.2 px
    rng = np.random.default_rng(7)
    uv_t = uv_true + np.array([0.0, -0.4]) + rng.normal(0, 0.2, uv_true.shape)
    desc = rng.normal(size=(len(uv_s), 32)).astype(np.float32)
    desc /= np.linalg.norm(desc, axis=1, keepdims=True)
    errors = {}
    for align in (False, True):
        fe = _front_end(align)
        target = _keyframe(fe, 0, uv_t, desc, pair["ct"], pair["dt"])
        source = _keyframe(fe, 1, uv_s, desc, pair["cs"], pair["ds"])
        res = fe._relative(source.points, source.features, target, T_t_s, True, source.view)
        assert res is not None
        t = T_t_s[:3, 3]
        errors[align] = float((res.T[:3, 3] - t) @ t / np.linalg.norm(t))  # along the motion, metres
    assert errors[False] > 0.004  # the stretch the detector's offset makes (> 1.3 % of 0.3 m)
    assert abs(errors[True]) < 0.001
