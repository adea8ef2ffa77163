"""experiments.update_growth: which keyframes an update added and how much of their view the map had."""

from __future__ import annotations

import math

import numpy as np

from litevloc.base.params.mapping import KeyframeParams
from litevloc.experiments.update_growth import added_nodes, seen_shares
from litevloc.pipelines.topomap.types import NodeFeatures, TopoMap
from tests.pipelines.topomap.test_diff import camera, grid, make_map

K = np.array([[50.0, 0.0, 32.0], [0.0, 50.0, 24.0], [0.0, 0.0, 1.0]])


def _with_views(m: TopoMap, depths_m: list[float]) -> TopoMap:
    """`m` with keyframe k seeing a grid of keypoints at `depths_m[k]` (K's 64 x 48 image)."""
    u, v = np.meshgrid(np.linspace(2, 62, 8), np.linspace(2, 46, 6))
    kp = np.stack([u.ravel(), v.ravel()], axis=1).astype(np.float32)
    feats = [NodeFeatures(kp, np.zeros((len(kp), 8), np.float32), np.ones(len(kp), np.float32), (64, 48),
                          np.full(len(kp), d, np.float32)) for d in depths_m]
    return TopoMap(m.T_map_camera, np.stack([K] * m.n_nodes), m.image_size, m.t_ns, m.frame_index, m.vpr,
                   list(feats), m.images_jpeg, m.covis_edges, m.covis_inliers, m.covis_weight, m.conn_edges,
                   m.conn_metres, m.grid)


def test_a_view_the_map_had_is_seen_one_it_never_had_is_not() -> None:
    g = grid(slice(0, 20), slice(0, 20))
    before = _with_views(make_map([camera(2, 5)], [b"a"], g), [3.0])
    # "b" stands 1 m behind "a" looking the same way (the wall "a" saw, from farther back); "c" looks back
    after = _with_views(make_map([camera(2, 5), camera(1, 5), camera(2, 5, 180)], [b"a", b"b", b"c"], g),
                        [3.0, 4.0, 3.0])
    assert added_nodes(before, after) == [1, 2]
    shares = seen_shares(before, after, KeyframeParams())
    assert shares[1] > 0.5 and shares[2] == 0.0
    assert added_nodes(after, after) == []


def test_a_keyframe_without_depth_has_no_share() -> None:
    g = grid(slice(0, 20), slice(0, 20))
    before = _with_views(make_map([camera(2, 5)], [b"a"], g), [3.0])
    after = _with_views(make_map([camera(2, 5), camera(1, 5)], [b"a", b"b"], g), [3.0, float("nan")])
    assert math.isnan(seen_shares(before, after, KeyframeParams())[1])
