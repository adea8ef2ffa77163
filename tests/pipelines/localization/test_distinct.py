"""GL's distinctiveness test (issue #43): a pose that another place verifies nearly as well
(a repeating corridor) is refused without a trusted prior."""

from __future__ import annotations

from dataclasses import replace

import pytest

from litevloc.base import geometry as g
from litevloc.base.params.localization import LocalizationParams
from litevloc.pipelines.localization.distinct import Rival, VerifiedPose, ambiguity, strongest_rival
from litevloc.pipelines.localization.vloc import VisualLocalizer
from litevloc.pipelines.topomap.types import NodeFeatures, TopoMap
from tests.pipelines.localization.test_vloc import IMG, PARAMS, K, Scene, make_map, pose

# re-ranking and guided matching off: over these large synthetic keypoint sets they dominate the time
GUARD = replace(PARAMS, gl_top_k=4, gl_distinct_ratio=2.0, gl_rerank=False,
                refine=replace(PARAMS.refine, extra_matching="model"))


def _corridor() -> TopoMap:
    """Keyframes at x = 0, 1 and at x = 10, 11 whose features are copies of the first two's:
    the same texture one period (10 m) along the corridor."""
    m = make_map([0.0, 1.0, 10.0, 11.0])
    feats = list(m.features)
    for k in (2, 3):
        f = feats[k - 2]
        feats[k] = NodeFeatures(f.keypoints.copy(), f.descriptors.copy(), f.scores.copy(), f.image_size)
    return replace(m, features=feats)


def test_rivals_are_candidates_at_another_pose_and_the_ratio_decides() -> None:
    win = pose(0.0)
    verified = [VerifiedPose(1, pose(0.05), 90), VerifiedPose(2, pose(10.0), 40), VerifiedPose(3, pose(0.0, 30.0), 20)]
    rival = strongest_rival(win, verified, 0.3, 10.0)
    assert rival is not None and rival.node == 2 and rival.apart_m == pytest.approx(10.0)
    assert strongest_rival(win, verified[:1], 0.3, 10.0) is None  # 5 cm away: the same place
    turned = strongest_rival(win, verified[2:], 0.3, 10.0)
    assert turned is not None and turned.apart_deg == pytest.approx(30.0)
    assert ambiguity(0, 100, Rival(2, 50, 10.0, 0.0), 2.0).startswith("ambiguous: node 0 (100 inliers) and node 2")
    assert ambiguity(0, 101, Rival(2, 50, 10.0, 0.0), 2.0) == ""
    assert ambiguity(0, 100, Rival(2, 99, 10.0, 0.0), 0.0) == ""  # off
    assert ambiguity(0, 100, None, 2.0) == ""
    with pytest.raises(ValueError, match="gl_distinct_ratio"):
        LocalizationParams(gl_distinct_ratio=0.5)


def test_gl_refuses_a_pose_that_another_place_verifies_as_well() -> None:
    m = _corridor()
    s = Scene(m)
    T_true = pose(0.3, 4.0)
    depth = s.look(T_true, vpr_best=0)
    s.vpr[2] = 0.9  # the aliased place ranks second
    off = VisualLocalizer(m, replace(GUARD, gl_distinct_ratio=0.0), s.extract, s.describe, s.match)
    assert off.localize_global(0, IMG, depth, K).accepted  # without the test: a fix at one of the two
    on = VisualLocalizer(m, GUARD, s.extract, s.describe, s.match)
    r = on.localize_global(0, IMG, depth, K)
    assert not r.accepted and r.T_map_camera is None and r.provisional is None
    assert "ambiguous" in r.reason and "10.00 m" in r.reason, r.reason
    # a fresh prior is trusted: the pose that agrees with it is accepted
    r = on.localize_global(0, IMG, depth, K, pose(0.4, 3.0), prior_age_s=0.1)
    assert r.accepted, r.reason
    assert g.relative_pose_error(r.T_map_camera, T_true)[0] < 0.01
    # the rivals verified after the winner are bounded
    none = VisualLocalizer(m, replace(GUARD, gl_distinct_max_rivals=0), s.extract, s.describe, s.match)
    assert none.localize_global(0, IMG, depth, K).accepted
    # where the other period does not verify (its matches garbage), the place is distinctive
    s.broken_nodes = {2, 3}
    r = on.localize_global(0, IMG, depth, K)
    assert r.accepted and g.relative_pose_error(r.T_map_camera, T_true)[0] < 0.01, r.reason



def test_lower_inlier_floor_only_where_the_distinctiveness_test_judges() -> None:
    m = make_map([0.0, 1.0])
    s = Scene(m)
    p = replace(GUARD, gl_distinct_min_inliers=12)
    loc = VisualLocalizer(m, p, s.extract, s.describe, s.match)
    assert loc._gl_params(trusted_prior=False).pnp.min_inliers == 12
    assert loc._gl_params(trusted_prior=True).pnp.min_inliers == p.pnp.min_inliers
    off = VisualLocalizer(m, replace(p, gl_distinct_ratio=0.0), s.extract, s.describe, s.match)
    assert off._gl_params(trusted_prior=False).pnp.min_inliers == p.pnp.min_inliers
    with pytest.raises(ValueError, match="gl_distinct_min_inliers"):
        LocalizationParams(gl_distinct_min_inliers=3)
