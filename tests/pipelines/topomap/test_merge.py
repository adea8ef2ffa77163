"""Session merge on real 7-Scenes frames (ORB test doubles): alignment vs the known frame
offset, robustness to wrong links, refusal without overlap, a consistent joined map."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from litevloc.base import geometry as g
from litevloc.pipelines.topomap.io import load_map
from litevloc.pipelines.topomap.map_save import save_map
from litevloc.pipelines.topomap.merge import (
    Link,
    MapMergeError,
    MergeParams,
    align,
    merge_sessions,
    transform_map,
)
from litevloc.pipelines.topomap.types import FeatureStore, TopoMap

from .helpers import build_7scenes, orb_match, seven_scenes_mapping

# the 7scenes preset's keyframe density (a small kitchen): ~22 keyframes per session
PARAMS = seven_scenes_mapping(budget=None)
T_B_A = g.make_T(g.so3_exp(np.array([0.1, -0.3, 0.7])), [3.0, -1.0, 0.5])  # session B's frame from A's


@pytest.fixture(scope="module")
def sessions(seven_scenes_dir: Path) -> tuple[TopoMap, TopoMap]:
    A = build_7scenes(seven_scenes_dir, "0:300:3", PARAMS).finish()
    B = build_7scenes(seven_scenes_dir, "200:500:3", PARAMS).finish()
    return A, transform_map(B, T_B_A)


def test_transform_map_keeps_the_grid_consistent(sessions: tuple[TopoMap, TopoMap]) -> None:
    A, _ = sessions
    moved = transform_map(A, T_B_A)
    # plane coordinates of the same physical points are unchanged by re-expression
    p = A.positions
    p_moved = p @ T_B_A[:3, :3].T + T_B_A[:3, 3]
    np.testing.assert_allclose(moved.grid.to_plane(p_moved) - moved.grid.origin,
                               A.grid.to_plane(p) - A.grid.origin, atol=1e-9)
    np.testing.assert_allclose(moved.positions, p_moved, atol=1e-9)
    back = transform_map(moved, g.invert(T_B_A))
    np.testing.assert_allclose(back.T_map_camera, A.T_map_camera, atol=1e-9)


def test_merge_recovers_the_frame_offset(sessions: tuple[TopoMap, TopoMap], tmp_path: Path) -> None:
    A, B = sessions
    merged, report, al, _links = merge_sessions(A, B, orb_match, MergeParams())
    dt, dr = g.relative_pose_error(al.T_A_B, g.invert(T_B_A))
    assert dt < 0.05 and dr < 1.0, (dt, dr)
    assert report.links_consistent >= 3
    assert merged.n_nodes == A.n_nodes + B.n_nodes - report.nodes_dropped
    # A's nodes are unchanged and first; B's kept nodes are in A's frame (= the truth here)
    np.testing.assert_allclose(merged.T_map_camera[: A.n_nodes], A.T_map_camera)
    # the sessions are joined for planning: some connectivity edge crosses sessions
    ce = merged.conn_edges
    assert np.any((ce[:, 0] < A.n_nodes) & (ce[:, 1] >= A.n_nodes))
    # the merged map is a valid map: save + load round trip with every check
    out = save_map(merged, tmp_path / "merged")
    again = load_map(out)
    assert again.n_nodes == merged.n_nodes and "merged_sessions" in again.meta


def test_merge_of_loaded_maps_keeps_keypoint_depth(sessions: tuple[TopoMap, TopoMap], tmp_path: Path) -> None:
    """Loaded maps are viewed through the matcher's converter (`check_map_models`), which has
    no keypoint depth; the merged map must still store it (metric goal poses need it)."""
    import dataclasses

    loaded = []
    for name, m in zip("AB", sessions, strict=True):
        store = load_map(save_map(m, tmp_path / name)).features
        assert isinstance(store, FeatureStore) and store.depth is not None
        loaded.append(dataclasses.replace(m, features=store.mapped(lambda f: dataclasses.replace(f, depth=None))))
    A, B = loaded
    assert getattr(A.features[0], "depth", None) is None  # what the converter hands the merge
    merged, _report, _al, _links = merge_sessions(A, B, orb_match, MergeParams())
    again = load_map(save_map(merged, tmp_path / "merged"))
    for node in range(again.n_nodes):
        z = again.keypoint_depth(node)
        assert z is not None and np.isfinite(z).any(), node
    np.testing.assert_allclose(again.keypoint_depth(0), A.keypoint_depth(0), rtol=1e-3)


def test_wrong_links_do_not_bend_the_alignment(sessions: tuple[TopoMap, TopoMap]) -> None:
    A, B = sessions
    _, _, al, links = merge_sessions(A, B, orb_match, MergeParams())
    rng = np.random.default_rng(0)
    bad = list(links)
    assert len(links) >= 10
    n_bad = max(1, len(links) // 3)  # a third of the links wrong: harder than the 10 % of the issue
    for k in rng.choice(len(links), size=n_bad, replace=False):
        dT = g.make_T(g.so3_exp(np.array([0.0, 0.0, np.radians(25)])), [1.5, -0.5, 0.2])
        bad[k] = Link(bad[k].a, bad[k].b, dT @ bad[k].T_A_B, bad[k].inliers, bad[k].similarity)
    al_bad = align(bad, B, MergeParams())
    shift = np.linalg.norm((B.positions @ (al.T_A_B[:3, :3] - al_bad.T_A_B[:3, :3]).T)
                           + (al.T_A_B[:3, 3] - al_bad.T_A_B[:3, 3]), axis=1).max()
    assert shift < 0.02, shift
    assert int((~al_bad.consistent).sum()) >= n_bad


def test_no_overlap_is_refused_with_the_reason(seven_scenes_dir: Path) -> None:
    A = build_7scenes(seven_scenes_dir, "0:60:3", PARAMS).finish()
    far = build_7scenes(seven_scenes_dir, "380:440:3", PARAMS).finish()
    with pytest.raises(MapMergeError, match="do not overlap enough"):
        merge_sessions(A, transform_map(far, T_B_A), orb_match, MergeParams(min_links=3))


def test_too_few_links_to_align() -> None:
    with pytest.raises(MapMergeError, match="0 verified cross-session links"):
        align([], None, MergeParams())  # type: ignore[arg-type]


def test_params_validated() -> None:
    with pytest.raises(ValueError, match="min_links"):
        MergeParams(min_links=0)
    with pytest.raises(ValueError, match="connect_m"):
        MergeParams(connect_m=float("inf"))
