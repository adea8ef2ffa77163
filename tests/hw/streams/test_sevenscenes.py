from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from litevloc.base.frames import parse_frames
from litevloc.hw.messages import GroundTruthPose, RgbdFrame, StreamError
from litevloc.hw.streams.sevenscenes import SevenScenesSource


def small_copy(src: Path, dst: Path, n: int = 4) -> Path:
    dst.mkdir()
    shutil.copy(src / "camera-intrinsics.txt", dst)
    for i in range(n):
        for ext in ("color.jpg", "depth.png", "pose.txt"):
            shutil.copy(src / f"frame-{i:06d}.{ext}", dst)
    return dst


def test_reads_frames_and_poses(seven_scenes_dir: Path) -> None:
    src = SevenScenesSource(seven_scenes_dir, parse_frames("10:13"))
    msgs = list(src)
    frames = [m for m in msgs if isinstance(m, RgbdFrame)]
    poses = [m for m in msgs if isinstance(m, GroundTruthPose)]
    assert [f.index for f in frames] == [10, 11, 12] and len(poses) == 3 and src.frame_count() == 3
    f = frames[0]
    assert f.color.shape == (480, 640, 3) and f.color.dtype == np.uint8
    assert f.depth is not None and f.depth.dtype == np.float32 and f.depth.shape == (480, 640)
    invalid = np.isnan(f.depth).mean()
    assert 0.0 < invalid < 0.3 and np.nanmax(f.depth) < 10
    assert np.allclose(f.K, [[585, 0, 320], [0, 585, 240], [0, 0, 1]])
    assert f.t_ns == round(10 * 1e9 / 30) and f.color_jpeg is not None
    expected = np.loadtxt(seven_scenes_dir / "frame-000010.pose.txt")
    assert np.allclose(poses[0].T_world_camera, expected, atol=1e-3)
    assert np.array_equal(poses[0].T_world_camera[:3, 3], expected[:3, 3])
    from litevloc.base.geometry import is_rigid

    assert is_rigid(poses[0].T_world_camera, atol=1e-9)


def test_missing_folder() -> None:
    with pytest.raises(StreamError, match="not found"):
        SevenScenesSource("/nonexistent/7scenes")


def test_empty_folder(tmp_path: Path) -> None:
    with pytest.raises(StreamError, match="not a 7-Scenes folder"):
        SevenScenesSource(tmp_path)


def test_truncated_jpeg_is_an_error_or_counted_skip(seven_scenes_dir: Path, tmp_path: Path) -> None:
    d = small_copy(seven_scenes_dir, tmp_path / "s")
    jpg = d / "frame-000001.color.jpg"
    jpg.write_bytes(jpg.read_bytes()[:5000])
    with pytest.raises(StreamError, match=r"truncated.*frame-000001\.color\.jpg"):
        list(SevenScenesSource(d))
    src = SevenScenesSource(d, strict=False)
    frames = [m for m in src if isinstance(m, RgbdFrame)]
    assert [f.index for f in frames] == [0, 2, 3] and src.stats.total_skipped == 1


def test_garbage_image_and_wrong_depth_size(seven_scenes_dir: Path, tmp_path: Path) -> None:
    import cv2

    d = small_copy(seven_scenes_dir, tmp_path / "s")
    (d / "frame-000000.color.jpg").write_bytes(b"not an image at all")
    with pytest.raises(StreamError, match="corrupt or not an image"):
        list(SevenScenesSource(d, parse_frames("0:1")))
    cv2.imwrite(str(d / "frame-000002.depth.png"), np.zeros((240, 320), np.uint16))
    with pytest.raises(StreamError, match=r"depth size 320x240 differs.*frame-000002"):
        list(SevenScenesSource(d, parse_frames("2:3")))
    (d / "frame-000003.depth.png").unlink()
    with pytest.raises(StreamError, match="depth image missing"):
        list(SevenScenesSource(d, parse_frames("3:4")))


def test_bad_pose_file(seven_scenes_dir: Path, tmp_path: Path) -> None:
    d = small_copy(seven_scenes_dir, tmp_path / "s")
    (d / "frame-000001.pose.txt").write_text("1 2 3\n")
    with pytest.raises(StreamError, match=r"4x4.*frame-000001\.pose\.txt"):
        SevenScenesSource(d)
    src = SevenScenesSource(d, strict=False)
    assert src.stats.total_skipped == 1


def test_frames_spec_parsing() -> None:
    assert parse_frames("0:500") == slice(0, 500)
    assert parse_frames("500:") == slice(500, None)
    assert parse_frames(None) == slice(None)
    assert parse_frames("::5") == slice(None, None, 5)
    for bad in ("a:b", "5", "1:2:0"):
        with pytest.raises(ValueError):
            parse_frames(bad)


def test_calibrated_reader_registers_depth_and_moves_ground_truth(seven_scenes_dir: Path) -> None:
    from litevloc.base.geometry import make_T, so3_exp

    K_color = np.array([[515.0, 0.0, 318.0], [0.0, 518.0, 226.0], [0.0, 0.0, 1.0]])
    T_cd = make_T(so3_exp(np.array([-0.019, -0.027, 0.0])), np.array([-0.025, 0.0, 0.0]))
    raw = list(SevenScenesSource(seven_scenes_dir, parse_frames("20:21")))
    cal = list(SevenScenesSource(seven_scenes_dir, parse_frames("20:21"), K_color=K_color, T_color_depth=T_cd))
    f_raw, gt_raw = raw[0], raw[1]
    f_cal, gt_cal = cal[0], cal[1]
    assert isinstance(f_raw, RgbdFrame) and isinstance(f_cal, RgbdFrame)
    assert isinstance(gt_raw, GroundTruthPose) and isinstance(gt_cal, GroundTruthPose)
    np.testing.assert_array_equal(f_cal.K, K_color)
    np.testing.assert_array_equal(f_cal.color, f_raw.color)
    np.testing.assert_allclose(gt_cal.T_world_camera, gt_raw.T_world_camera @ np.linalg.inv(T_cd), atol=1e-12)
    assert f_cal.depth is not None and f_raw.depth is not None and f_cal.depth.shape == f_raw.depth.shape
    # Same surface, other camera: similar depth statistics, but not the same image.
    assert abs(np.nanmedian(f_cal.depth) - np.nanmedian(f_raw.depth)) < 0.05
    assert not np.allclose(np.nan_to_num(f_cal.depth), np.nan_to_num(f_raw.depth))
    # Identity extrinsic and the depth intrinsics: depth unchanged.
    same = list(SevenScenesSource(seven_scenes_dir, parse_frames("20:21"), K_color=f_raw.K, T_color_depth=np.eye(4)))
    assert isinstance(same[0], RgbdFrame) and same[0].depth is not None
    np.testing.assert_allclose(same[0].depth, f_raw.depth, equal_nan=True)
    with pytest.raises(StreamError, match="both"):
        SevenScenesSource(seven_scenes_dir, parse_frames("20:21"), K_color=K_color)


def test_colour_distortion_is_removed_to_the_pinhole_intrinsics(seven_scenes_dir: Path) -> None:
    """With k1, k2 the colour image is resampled so that a pixel p of the output shows what
    the lens put at distort(p): the centre stays, the corners move by the model's amount."""
    import cv2

    K = np.array([[520.0, 0.0, 315.0], [0.0, 520.0, 225.0], [0.0, 0.0, 1.0]])
    k1, k2 = -0.07, 0.02
    raw = list(SevenScenesSource(seven_scenes_dir, parse_frames("20:21"), K_color=K, T_color_depth=np.eye(4)))
    und = list(SevenScenesSource(seven_scenes_dir, parse_frames("20:21"), K_color=K, T_color_depth=np.eye(4),
                                 color_k1_k2=(k1, k2)))
    f_raw, f_und = raw[0], und[0]
    assert isinstance(f_raw, RgbdFrame) and isinstance(f_und, RgbdFrame)
    assert f_und.color.shape == f_raw.color.shape and f_und.color.dtype == np.uint8
    np.testing.assert_array_equal(f_und.K, K)
    # a patch near a corner of the output equals the raw image around the distorted position
    u, v = 80.0, 70.0
    xn = np.array([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1]])
    r2 = float(xn @ xn)
    ud, vd = xn * (1 + k1 * r2 + k2 * r2 * r2) * K[0, 0] + K[:2, 2]
    assert np.hypot(ud - u, vd - v) > 5  # the model moves this pixel by several pixels
    g_raw = cv2.cvtColor(f_raw.color, cv2.COLOR_RGB2GRAY).astype(np.float32)
    g_und = cv2.cvtColor(f_und.color, cv2.COLOR_RGB2GRAY).astype(np.float32)
    patch = g_und[int(v) - 8:int(v) + 9, int(u) - 8:int(u) + 9]
    moved = cv2.getRectSubPix(g_raw, (17, 17), (float(ud), float(vd)))
    unmoved = g_raw[int(v) - 8:int(v) + 9, int(u) - 8:int(u) + 9]
    assert np.abs(patch - moved).mean() < 0.5 * np.abs(patch - unmoved).mean()
    with pytest.raises(StreamError, match="distortion"):
        SevenScenesSource(seven_scenes_dir, parse_frames("20:21"), color_k1_k2=(k1, k2))
