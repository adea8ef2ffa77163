from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from litevloc.hw.messages import GroundTruthPose, RgbdFrame, StreamError
from litevloc.hw.streams.tum import TumRgbdSource


def make_tum(root: Path, n: int = 5) -> Path:
    root.mkdir()
    (root / "rgb").mkdir()
    (root / "depth").mkdir()
    rgb_lines, depth_lines, gt_lines = ["# color"], ["# depth"], ["# gt"]
    for i in range(n):
        t = 1000.0 + i * 0.1
        cv2.imwrite(str(root / f"rgb/{t:.6f}.png"), np.full((48, 64, 3), 20 * i, np.uint8))
        cv2.imwrite(str(root / f"depth/{t + 0.005:.6f}.png"), np.full((48, 64), 5000 + i, np.uint16))
        rgb_lines.append(f"{t:.6f} rgb/{t:.6f}.png")
        depth_lines.append(f"{t + 0.005:.6f} depth/{t + 0.005:.6f}.png")
    for i in range(2 * n):
        t = 999.95 + i * 0.05
        gt_lines.append(f"{t:.4f} {i * 0.1:.3f} 0 0 0 0 0 1")
    (root / "rgb.txt").write_text("\n".join(rgb_lines) + "\n")
    (root / "depth.txt").write_text("\n".join(depth_lines) + "\n")
    (root / "groundtruth.txt").write_text("\n".join(gt_lines) + "\n")
    np.savetxt(root / "intrinsics.txt", np.array([[50, 0, 32], [0, 50, 24], [0, 0, 1.0]]))
    return root


def test_tum_association_scale_and_gt(tmp_path: Path) -> None:
    src = TumRgbdSource(make_tum(tmp_path / "rgbd_dataset_freiburg1_xyz"))
    msgs = list(src)
    frames = [m for m in msgs if isinstance(m, RgbdFrame)]
    gts = [m for m in msgs if isinstance(m, GroundTruthPose)]
    assert len(frames) == 5 and len(gts) == 5
    assert frames[0].depth is not None and np.allclose(frames[0].depth, 1.0)
    assert np.allclose(frames[2].depth, (5000 + 2) / 5000)
    assert frames[1].t_ns == 1_000_100_000_000
    # gt x = 2 * (t - 999.95) -> at t = 1000.1: 0.3 m
    assert np.isclose(gts[1].T_world_camera[0, 3], 0.3, atol=1e-6)


def test_tum_errors(tmp_path: Path) -> None:
    root = make_tum(tmp_path / "seq")
    (root / "intrinsics.txt").unlink()
    with pytest.raises(StreamError, match=r"no intrinsics\.txt"):
        TumRgbdSource(root)
    root2 = make_tum(tmp_path / "rgbd_dataset_freiburg2_x")
    (root2 / "rgb.txt").write_text("1000.0\n")
    with pytest.raises(StreamError, match=r"rgb\.txt:1: expected 2 columns"):
        TumRgbdSource(root2)
    root3 = make_tum(tmp_path / "freiburg3_y")
    (root3 / "groundtruth.txt").write_text("1000.0 0 0 0 0 0 0 0\n1000.1 0 0 0 0 0 0 1\n")
    with pytest.raises(StreamError, match="malformed pose"):
        TumRgbdSource(root3)
