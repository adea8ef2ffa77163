"""Map update on real 7-Scenes frames (ORB test doubles, ground-truth poses standing in for
the localizer): an unchanged revisit changes nothing, new places add keyframes, keyframes
whose appearance no longer matches are retired and replaced."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Iterator
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree

from litevloc.base.frames import parse_frames
from litevloc.base.geometry import backproject_depth
from litevloc.base.params.localization import DepthLookupParams
from litevloc.base.params.map_maintenance import ReplaceParams
from litevloc.hw.messages import GroundTruthPose, RgbdFrame
from litevloc.hw.streams.sevenscenes import SevenScenesSource
from litevloc.pipelines.depth_lookup import depth_at
from litevloc.pipelines.topomap.io import load_map
from litevloc.pipelines.topomap.map_save import save_map
from litevloc.pipelines.topomap.types import NodeFeatures, TopoMap
from litevloc.pipelines.topomap.update import (
    MapUpdate,
    Observation,
    UpdateParams,
    consistent_matches,
    guided_consistent_matches,
)

from .helpers import build_7scenes, orb_extract, orb_match, seven_scenes_mapping, thumb_describe

PARAMS = seven_scenes_mapping(budget=None)


def observations(folder: Path, frames: str, quality_map: TopoMap | None = None) -> Iterator[Observation]:
    """Frames with ground-truth poses as the 'localization'; with `quality_map`, the
    localization's inlier count is stood in for by the frame's best consistent matches with
    that (unchanged) map's covering keyframes."""
    judge = MapUpdate(quality_map, orb_match) if quality_map is not None else None
    pending: RgbdFrame | None = None
    for m in SevenScenesSource(folder, parse_frames(frames)):
        if isinstance(m, RgbdFrame):
            pending = m
        elif isinstance(m, GroundTruthPose) and pending is not None and pending.t_ns == m.t_ns:
            f, T = pending, m.T_world_camera
            assert f.depth is not None
            feats = orb_extract(f.color)
            pts, _ = backproject_depth(f.depth, f.K, stride=16)
            h, w = f.color.shape[:2]
            nf = NodeFeatures(feats.keypoints, feats.descriptors, feats.scores, (w, h))
            kd = depth_at(f.depth, feats.keypoints, DepthLookupParams())
            quality = 0
            if judge is not None:
                qm = judge.map
                quality = max((consistent_matches(T, nf, kd, f.K, qm.features[n], qm.T_map_camera[n], qm.K[n],
                                                  orb_match, 4.0) for n in judge.covering_nodes(T)), default=0)
            yield Observation(f.t_ns, f.index, T, f.K, (w, h), nf, kd, thumb_describe(f.color),
                              f.color_jpeg or b"", (pts @ T[:3, :3].T + T[:3, 3]).astype(np.float32), quality)
            pending = None


@pytest.fixture(scope="module")
def base_map(seven_scenes_dir: Path) -> TopoMap:
    return build_7scenes(seven_scenes_dir, "0:250:3", PARAMS).finish()


def run_update(m: TopoMap, folder: Path, frames: str, quality_map: TopoMap | None = None,
               params: UpdateParams | None = None, finish: bool = True,
               observed: Iterable[Observation] | None = None) -> tuple[TopoMap | None, MapUpdate]:
    """The updated map (None without `finish`: the report and candidates only) and the update.
    `observed`: the frames' observations made once beforehand (`observations(folder, frames,
    quality_map)`), for two updates of the same frames."""
    upd = MapUpdate(m, orb_match, params or UpdateParams())
    for obs in observations(folder, frames, quality_map) if observed is None else observed:
        upd.observe(obs)
    if not finish:
        return None, upd
    new, _ = upd.finish(PARAMS.covisibility, PARAMS.connectivity, PARAMS.occupancy)
    return new, upd


def test_unchanged_revisit_changes_nothing(base_map: TopoMap, seven_scenes_dir: Path) -> None:
    new, upd = run_update(base_map, seven_scenes_dir, "1:250:6")  # other frames of the same pass
    r = upd.report
    assert r.retired == [] and len(r.added) <= 0.1 * base_map.n_nodes, (r.retired, r.added)
    assert r.known >= 0.8 * r.frames
    np.testing.assert_allclose(new.T_map_camera[: base_map.n_nodes], base_map.T_map_camera)


def test_frames_between_keyframes_that_match_are_known_places(base_map: TopoMap, seven_scenes_dir: Path) -> None:
    # a place radius too small for any keyframe to cover a frame: only the matches of the
    # nearby keyframes can tell that the map already knows these views (#18: corridor frames
    # between keyframes more than place_radius_m apart counted as new places)
    tight = UpdateParams(mapped_view=False, place_radius_m=1e-3, match_radius_m=1e-3, min_spacing_m=0.01)
    _, radius_only = run_update(base_map, seven_scenes_dir, "1:250:12", params=tight, finish=False)
    _, by_matches = run_update(base_map, seven_scenes_dir, "1:250:12",
                               params=dataclasses.replace(tight, match_radius_m=1.5), finish=False)
    a, b = radius_only.report, by_matches.report
    assert a.frames == b.frames > 10
    assert a.new_place >= 0.9 * a.frames, a
    assert b.known >= 0.8 * b.frames, b
    assert len(by_matches.candidates) <= 0.2 * len(radius_only.candidates) + 1


def test_new_places_add_keyframes(base_map: TopoMap, seven_scenes_dir: Path, tmp_path: Path) -> None:
    new, upd = run_update(base_map, seven_scenes_dir, "250:500:5")
    r = upd.report
    assert r.new_place > 0 and len(r.added) > 0 and r.retired == []
    assert new.n_nodes == base_map.n_nodes + len(r.added)
    # every added keyframe is tied into both graphs
    added = set(r.added)
    assert all(any(a in e for e in new.conn_edges.tolist()) for a in added)
    assert any(set(e) & added for e in new.covis_edges.tolist())
    # the new version is a valid map
    again = load_map(save_map(new, tmp_path / "v2"))
    assert again.n_nodes == new.n_nodes


def test_frames_an_added_keyframe_explains_add_nothing(base_map: TopoMap, seven_scenes_dir: Path) -> None:
    """A frame that no old keyframe explains is compared with the keyframes the update has
    added: along a new path a keyframe is added where the last added one stops matching, not
    at every spacing step."""
    # (a place radius too small for any old keyframe to cover or explain a frame: every frame
    # is at a new place, as on a path the map never saw)
    tight = UpdateParams(mapped_view=False, place_radius_m=1e-3, match_radius_m=1e-3, min_spacing_m=0.01,
                         min_spacing_deg=1.0)
    reach = dataclasses.replace(tight, match_radius_m=1.5)  # ... but added keyframes reach 1.5 m
    frames = list(observations(seven_scenes_dir, "250:500:10"))
    only_spacing = MapUpdate(base_map, orb_match, tight)
    chained = MapUpdate(base_map, orb_match, reach)
    chained._tree = only_spacing._tree = cKDTree(np.full((1, 3), 1e6))  # the old keyframes out of reach
    for obs in frames:
        only_spacing.observe(obs)
        chained.observe(obs)
    a, b = only_spacing.report, chained.report
    assert a.new_place == a.frames == b.frames == len(frames) and a.known_by_added == 0
    assert b.known_by_added == b.known >= 0.3 * b.frames, b
    assert 0 < len(chained.candidates) <= 0.7 * len(only_spacing.candidates), (len(chained.candidates),
                                                                              len(only_spacing.candidates))


def test_changed_appearance_retires_and_replaces(base_map: TopoMap, seven_scenes_dir: Path) -> None:
    # "re-textured": the stored features of three keyframes no longer match anything
    rng = np.random.default_rng(0)
    changed = [2, 5, 9]
    feats = list(base_map.features)
    for i in changed:
        f = feats[i]
        feats[i] = NodeFeatures(f.keypoints, rng.integers(0, 256, f.descriptors.shape, dtype=np.uint8), f.scores,
                                f.image_size)
    m = dataclasses.replace(base_map, features=feats)
    observed = list(observations(seven_scenes_dir, "1:250:4", base_map))  # both updates below see these frames
    new, upd = run_update(m, seven_scenes_dir, "1:250:4", quality_map=base_map, observed=observed)
    r = upd.report
    assert set(changed) <= set(r.retired), r.retired
    assert len(r.retired) <= len(changed) + 1
    assert r.changed_place > 0 and len(r.added) > 0
    assert len(r.added) < 0.3 * base_map.n_nodes + len(changed)
    assert new.n_nodes == base_map.n_nodes - len(r.retired) + len(r.added)
    assert set(r.replaced) <= set(r.retired)
    assert sum(r.replace_outcomes.values()) >= 1  # the changed-place candidates were judged
    # without replacement every changed-place candidate is added: never fewer keyframes than with it
    plain, _ = run_update(m, seven_scenes_dir, "1:250:4", quality_map=base_map,
                          params=UpdateParams(replace=ReplaceParams(enabled=False)), observed=observed)
    assert plain is not None and new.n_nodes <= plain.n_nodes


def test_params_validated() -> None:
    with pytest.raises(ValueError, match="retire_max_consistent"):
        UpdateParams(retire_max_consistent=50, changed_max_consistent=40)
    with pytest.raises(ValueError, match="match_radius_m"):
        UpdateParams(place_radius_m=1.0, match_radius_m=0.5)


def test_update_of_a_loaded_map_keeps_keypoint_depth(base_map: TopoMap, seven_scenes_dir: Path,
                                                     tmp_path: Path) -> None:
    """The runtime views a loaded map through the matcher's converter, which has no keypoint
    depth; the kept nodes of the new version must still store it."""
    store = load_map(save_map(base_map, tmp_path / "v1")).features
    viewed = dataclasses.replace(base_map, features=store.mapped(lambda f: dataclasses.replace(f, depth=None)))
    assert getattr(viewed.features[0], "depth", None) is None
    new, upd = run_update(viewed, seven_scenes_dir, "250:500:25")
    assert upd.report.retired == []  # the old nodes come first, in order
    again = load_map(save_map(new, tmp_path / "v2"))
    for node in range(base_map.n_nodes):  # (this test's observations carry no depth of their own)
        z = again.keypoint_depth(node)
        assert z is not None and np.isfinite(z).any(), node


def test_localization_is_asked_for_only_where_the_keyframes_do_not_match(base_map: TopoMap,
                                                                         seven_scenes_dir: Path) -> None:
    """A posed session localizes a frame only where no keyframe explains it (known from
    elsewhere, new, changed or unreliable?): frames that the nearby keyframes already explain
    never call `localize`."""
    upd = MapUpdate(base_map, orb_match)
    asked: list[int] = []
    statuses = []
    for obs in observations(seven_scenes_dir, "1:250:12"):
        statuses.append(upd.observe(obs, localize=lambda i=obs.index: asked.append(i) or 0))
    known = statuses.count("known")
    assert known >= 0.8 * len(statuses) and 0 < len(asked) <= len(statuses) - known, (statuses, asked)
    assert upd.report.known_by_localization == 0  # (every localization here failed)
    # a frame no keyframe covers: a new place unless the map localizes it well from elsewhere
    tight = UpdateParams(mapped_view=False, place_radius_m=1e-3, match_radius_m=1e-3, min_spacing_m=0.01)
    obs = next(iter(observations(seven_scenes_dir, "1:250:12")))
    assert MapUpdate(base_map, orb_match, tight).observe(obs, localize=lambda: 0) == "new place"
    by_loc = MapUpdate(base_map, orb_match, tight)
    assert by_loc.observe(obs, localize=lambda: 100) == "known" and by_loc.report.known_by_localization == 1
    assert by_loc.candidates == []
    # a localization with enough support turns an otherwise unreliable frame into a changed place
    rng = np.random.default_rng(1)
    feats = [NodeFeatures(f.keypoints, rng.integers(0, 256, f.descriptors.shape, dtype=np.uint8), f.scores,
                          f.image_size) for f in base_map.features]
    scrambled = dataclasses.replace(base_map, features=feats)
    obs = next(o for o in observations(seven_scenes_dir, "1:250:12") if MapUpdate(scrambled, orb_match)
               .covering_nodes(o.T_map_camera))
    assert MapUpdate(scrambled, orb_match).observe(obs, localize=lambda: 0) == "unreliable"
    assert MapUpdate(scrambled, orb_match).observe(obs, localize=lambda: 100) == "changed place"


def test_candidates_are_spaced_by_the_place_they_cover() -> None:
    p = UpdateParams()
    assert (p.min_spacing_m, p.min_spacing_deg) == (p.place_radius_m, p.place_angle_deg)


def test_the_first_keyframe_that_explains_the_frame_ends_the_search(base_map: TopoMap,
                                                                    seven_scenes_dir: Path) -> None:
    calls = [0]

    def counting(a, b):  # type: ignore[no-untyped-def]
        calls[0] += 1
        return orb_match(a, b)

    upd = MapUpdate(base_map, counting, UpdateParams(matching="model"))
    frames = list(observations(seven_scenes_dir, "1:250:12"))
    near = [len(upd.nearby_nodes(o.T_map_camera, upd.params.match_radius_m)[: upd.params.nodes_checked])
            for o in frames]
    statuses = [upd.observe(o) for o in frames]
    assert statuses.count("known") >= 0.8 * len(frames)
    assert sum(near) >= 2 * len(frames)  # up to 3 keyframes were within reach of most frames ...
    assert calls[0] <= 1.3 * len(frames), (calls[0], len(frames), sum(near))  # ... one was matched


def test_guided_consistency_counts_what_the_pose_explains(base_map: TopoMap, seven_scenes_dir: Path) -> None:
    """The default consistency check finds its matches by the pose: a right pose explains
    about as many as the matcher's, a pose 0.3 m off or a re-textured keyframe almost none."""
    upd = MapUpdate(base_map, orb_match)
    assert upd.params.matching == "guided"
    m = base_map
    pairs = 0
    for obs in observations(seven_scenes_dir, "1:250:25"):
        node = upd.covering_nodes(obs.T_map_camera)[:1]
        if not node:
            continue
        n = node[0]
        args = (obs.features, obs.keypoint_depth, obs.K, m.features[n], m.T_map_camera[n], m.K[n])
        model = consistent_matches(obs.T_map_camera, *args[:6], orb_match, 4.0)
        guided = guided_consistent_matches(obs.T_map_camera, *args, 4.0, 0.6)
        if model < 40:
            continue
        pairs += 1
        assert guided >= 0.5 * model, (obs.index, n, model, guided)
        off = obs.T_map_camera.copy()
        off[:3, 3] += [0.3, 0.0, 0.0]
        assert guided_consistent_matches(off, *args, 4.0, 0.6) <= 0.2 * guided
        f = m.features[n]
        rng = np.random.default_rng(obs.index)
        scrambled = NodeFeatures(f.keypoints, rng.integers(0, 256, f.descriptors.shape, dtype=np.uint8), f.scores,
                                 f.image_size)
        assert guided_consistent_matches(obs.T_map_camera, *args[:3], scrambled, *args[4:], 4.0, 0.6) < 10
    assert pairs >= 3


def test_a_view_the_map_saw_from_elsewhere_is_not_a_new_place(base_map: TopoMap, seven_scenes_dir: Path) -> None:
    """No keyframe covers the frame and none nearby matches it (a radius too small), but the map's
    keyframes saw its view: it is a mapped place that nothing matches, skipped and counted, not a
    keyframe candidate; the same frame 50 m away, a view the map never saw, is a new place."""
    tight = UpdateParams(place_radius_m=1e-3, match_radius_m=1e-3, min_spacing_m=0.01)
    probe = MapUpdate(base_map, orb_match, tight)
    obs = next(o for o in observations(seven_scenes_dir, "1:250:12") if probe.seen_share(o) >= 0.9)
    upd = MapUpdate(base_map, orb_match, tight)
    assert upd.observe(obs, localize=lambda: 0) == "unreliable"
    assert (upd.report.mapped_view_unmatched, upd.report.new_place, upd.candidates) == (1, 0, [])
    T_far = obs.T_map_camera.copy()
    T_far[:3, 3] += [50.0, 0.0, 0.0]
    far = dataclasses.replace(obs, T_map_camera=T_far)
    assert upd.seen_share(far) == 0.0
    assert upd.observe(far, localize=lambda: 0) == "new place" and len(upd.candidates) == 1
    off = MapUpdate(base_map, orb_match, dataclasses.replace(tight, mapped_view=False))
    assert off.observe(obs, localize=lambda: 0) == "new place"
