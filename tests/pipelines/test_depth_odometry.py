"""Depth odometry (OpenCV cv2.Odometry) on real 7-Scenes frames."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from litevloc.base.geometry import invert
from litevloc.base.params.depth import DepthOdometryParams
from litevloc.hw.messages import RgbdFrame
from litevloc.hw.streams.sevenscenes import SevenScenesSource
from litevloc.pipelines.depth_odometry import DepthOdometry


@pytest.mark.shared_data
def test_depth_odometry_tracks_consecutive_frames(seven_scenes_dir: Path) -> None:
    src = SevenScenesSource(seven_scenes_dir, slice(500, 530, 3))
    _, gt = src.ground_truth()
    do = DepthOdometry(src.K)
    errs, motion = [], []
    for i, m in enumerate(x for x in src if isinstance(x, RgbdFrame)):
        r = do.step(None, m.depth)
        if i == 0:
            assert r.ok and np.allclose(r.T_prev_curr, np.eye(4))
            continue
        assert r.ok
        G = invert(gt[i - 1]) @ gt[i]  # T_prev_curr from ground truth
        errs.append(np.linalg.norm(r.T_prev_curr[:3, 3] - G[:3, 3]))
        motion.append(np.linalg.norm(G[:3, 3]))
    assert do.failures == 0
    assert np.median(errs) < 0.5 * np.median(motion)  # much better than assuming no motion
    assert np.median(errs) < 0.008


def test_depth_odometry_validates_input() -> None:
    with pytest.raises(ValueError, match="method"):
        DepthOdometryParams(method="icp")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="K"):
        DepthOdometry(np.zeros((3, 3)))
    K = np.array([[500.0, 0, 32], [0, 500, 24], [0, 0, 1]])
    do = DepthOdometry(K, DepthOdometryParams(method="rgbd"))
    with pytest.raises(ValueError, match="colour"):
        do.step(None, np.ones((48, 64), np.float32))
