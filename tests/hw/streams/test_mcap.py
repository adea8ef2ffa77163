from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from litevloc.base import geometry as g
from litevloc.base.frames import parse_frames
from litevloc.hw import ros_msgs
from litevloc.hw.messages import (
    GroundTruthPose,
    Odometry,
    RgbdFrame,
    StreamError,
    depth_to_millimetres,
)
from litevloc.hw.streams.mcap_io import TOPIC_ODOM, McapRecorder, McapSource
from litevloc.hw.streams.sevenscenes import SevenScenesSource


def synthetic_messages(n: int = 6) -> list:
    rng = np.random.default_rng(0)
    K = np.array([[60.0, 0, 32], [0, 60, 24], [0, 0, 1]])
    out: list = []
    for i in range(n):
        t = 1_000_000_000 + i * 50_000_000
        out.append(Odometry(t - 1, g.make_T(g.so3_exp(rng.normal(size=3)), rng.normal(size=3))))
        color = np.zeros((48, 64, 3), np.uint8)
        color[:, :, 0] = np.arange(64, dtype=np.uint8)[None, :] * 3
        color[:, :, 1] = 100 + i
        depth = rng.uniform(0.3, 5, (48, 64)).astype(np.float32)
        depth[0, :5] = np.nan
        out.append(RgbdFrame(t, color, depth, K, index=i))
        out.append(GroundTruthPose(t, g.make_T(g.so3_exp(rng.normal(size=3)), rng.normal(size=3))))
    return out


def write(path: Path, msgs: list) -> None:
    with McapRecorder(path) as rec:
        for m in msgs:
            rec.write(m)


def test_synthetic_round_trip(tmp_path: Path) -> None:
    msgs = synthetic_messages()
    write(tmp_path / "a.mcap", msgs)
    back = list(McapSource(tmp_path / "a.mcap"))
    assert [type(m) for m in back] == [type(m) for m in msgs]
    for a, b in zip(msgs, back, strict=True):
        assert a.t_ns == b.t_ns
        if isinstance(a, RgbdFrame):
            assert np.abs(a.color.astype(int) - b.color.astype(int)).mean() < 2.0  # JPEG q95
            mm = depth_to_millimetres(a.depth).astype(np.float32)
            assert np.array_equal(np.isnan(a.depth), np.isnan(b.depth))
            ok = ~np.isnan(a.depth)
            assert np.array_equal(mm[ok], np.round(b.depth[ok] * 1000))  # millimetre-exact
            assert np.array_equal(a.K, b.K) and a.index == b.index
        elif isinstance(a, Odometry):
            assert np.allclose(a.T_odom_base, b.T_odom_base, atol=1e-12)
        else:
            assert np.allclose(a.T_world_camera, b.T_world_camera, atol=1e-12)


def test_dataset_round_trip_and_standard_decoder(seven_scenes_dir: Path, tmp_path: Path) -> None:
    src = SevenScenesSource(seven_scenes_dir, parse_frames("0:8"))
    msgs = list(src)
    write(tmp_path / "s.mcap", msgs)
    back = list(McapSource(tmp_path / "s.mcap"))
    assert len(back) == len(msgs) == 16
    for a, b in zip(msgs, back, strict=True):
        if isinstance(a, RgbdFrame):
            assert isinstance(b, RgbdFrame)
            assert np.array_equal(a.color, b.color)  # JPEG passed through, no re-encoding
            assert np.array_equal(np.nan_to_num(a.depth, nan=-1), np.nan_to_num(b.depth, nan=-1))  # exact
        else:
            assert np.allclose(a.T_world_camera, b.T_world_camera, atol=1e-12)
    # The file is standard: the mcap library's reader + the ROS 2 decoder read it.
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    with open(tmp_path / "s.mcap", "rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        decoded = list(reader.iter_decoded_messages())
    types = {schema.name for schema, _, _, _ in decoded}
    assert types == {"sensor_msgs/msg/CompressedImage", "sensor_msgs/msg/Image", "sensor_msgs/msg/CameraInfo",
                     "geometry_msgs/msg/PoseStamped"}
    depth_msgs = [m for s, _, _, m in decoded if s.name == "sensor_msgs/msg/Image"]
    assert depth_msgs[0].encoding == "16UC1" and depth_msgs[0].width == 640


def test_frames_selection_keeps_window(tmp_path: Path) -> None:
    write(tmp_path / "a.mcap", synthetic_messages(6))
    src = McapSource(tmp_path / "a.mcap", parse_frames("2:4"))
    back = list(src)
    frames = [m.index for m in back if isinstance(m, RgbdFrame)]
    assert frames == [2, 3] and src.frame_count() == 2
    lo, hi = 1_000_000_000 + 2 * 50_000_000, 1_000_000_000 + 3 * 50_000_000
    assert all(lo <= m.t_ns <= hi for m in back)


def test_truncated_and_garbage_files(tmp_path: Path) -> None:
    write(tmp_path / "a.mcap", synthetic_messages(4))
    data = (tmp_path / "a.mcap").read_bytes()
    (tmp_path / "t.mcap").write_bytes(data[: len(data) // 2])
    with pytest.raises(StreamError, match=r"t\.mcap"):
        list(McapSource(tmp_path / "t.mcap"))
    (tmp_path / "g.mcap").write_bytes(b"\x00garbage" * 100)
    with pytest.raises(StreamError, match=r"g\.mcap: not a readable MCAP"):
        McapSource(tmp_path / "g.mcap")
    with pytest.raises(StreamError, match="not found"):
        McapSource(tmp_path / "none.mcap")


def test_backwards_time_and_bad_payload(tmp_path: Path) -> None:
    msgs = synthetic_messages(3)
    odo = [m for m in msgs if isinstance(m, Odometry)]
    path = tmp_path / "b.mcap"
    with McapRecorder(path) as rec:
        rec.write(odo[1])
        older = ros_msgs.odometry_msg(odo[0].t_ns, odo[0].T_odom_base, "odom", "base_link")
        rec._put(TOPIC_ODOM, odo[1].t_ns + 1, older)
        rec._writer.add_message(channel_id=rec._channel(TOPIC_ODOM), log_time=odo[1].t_ns + 2,
                                publish_time=odo[1].t_ns + 2, data=b"\x00\x01\x00\x00garbage")
        rec.write(odo[2])
    with pytest.raises(StreamError, match="timestamps go backwards on /odom"):
        list(McapSource(path))
    live = McapSource(path, strict=False)
    out = list(live)
    assert len(out) == 2
    assert live.stats.skipped == {"timestamps go backwards on /odom": 1, "undecodable /odom message": 1}


def test_nan_pose_is_rejected(tmp_path: Path) -> None:
    T = np.eye(4)
    path = tmp_path / "n.mcap"
    with McapRecorder(path) as rec:
        msg = ros_msgs.odometry_msg(5, T, "odom", "base_link")
        msg.pose.pose.position.x = float("nan")
        rec._put(TOPIC_ODOM, 5, msg)
    with pytest.raises(StreamError, match="NaN"):
        list(McapSource(path))


def test_deferred_colour_decodes_to_the_same_frames(tmp_path: Path) -> None:
    """`messages(defer_color=True)` yields the same messages with frames as `EncodedRgbdFrame`;
    decoding one gives exactly the eagerly read frame (pixels, depth, K, stamp, JPEG bytes)."""
    from litevloc.hw.messages import EncodedRgbdFrame

    write(tmp_path / "a.mcap", synthetic_messages())
    eager = list(McapSource(tmp_path / "a.mcap", strict=False))
    lazy = list(McapSource(tmp_path / "a.mcap", strict=False).messages(defer_color=True))
    assert len(eager) == len(lazy)
    n_frames = 0
    for a, b in zip(eager, lazy, strict=True):
        if isinstance(a, RgbdFrame):
            assert isinstance(b, EncodedRgbdFrame) and b.color_data == a.color_jpeg
            d = b.decode()
            assert np.array_equal(d.color, a.color) and np.array_equal(d.K, a.K)
            assert np.array_equal(np.isnan(d.depth), np.isnan(a.depth))
            assert np.array_equal(d.depth[~np.isnan(d.depth)], a.depth[~np.isnan(a.depth)])
            assert (d.t_ns, d.index, d.frame_id, d.color_jpeg) == (a.t_ns, a.index, a.frame_id, a.color_jpeg)
            n_frames += 1
        else:
            assert type(a) is type(b) and a.t_ns == b.t_ns
    assert n_frames == 6
    strict = list(McapSource(tmp_path / "a.mcap").messages(defer_color=True))  # map build's read
    assert [type(m) for m in strict] == [type(m) for m in lazy]


def test_deferred_corrupt_colour_fails_at_decode_naming_the_frame(tmp_path: Path) -> None:
    import dataclasses

    from litevloc.hw.messages import EncodedRgbdFrame

    msgs = synthetic_messages(2)
    frames = [i for i, m in enumerate(msgs) if isinstance(m, RgbdFrame)]
    msgs[frames[1]] = dataclasses.replace(msgs[frames[1]], color_jpeg=b"\xff\xd8\xff\xe0 cut short")
    write(tmp_path / "c.mcap", msgs)
    lazy = [m for m in McapSource(tmp_path / "c.mcap", strict=False).messages(defer_color=True)
            if not isinstance(m, Odometry | GroundTruthPose)]
    assert len(lazy) == 2
    lazy[0].decode()
    with pytest.raises(StreamError, match=r"truncated.*c\.mcap colour at"):
        lazy[1].decode()
    # read strictly but deferred (map build), the frame comes and its decode raises
    strict = [m for m in McapSource(tmp_path / "c.mcap").messages(defer_color=True) if isinstance(m, EncodedRgbdFrame)]
    with pytest.raises(StreamError, match="truncated"):
        strict[1].decode()
    # read eagerly, the same frame is counted and skipped by the reader
    live = McapSource(tmp_path / "c.mcap", strict=False)
    assert sum(isinstance(m, RgbdFrame) for m in live) == 1 and live.stats.skipped == {"bad frame": 1}


def test_without_odometry_gives_every_other_message_as_iterating_does(tmp_path: Path) -> None:
    write(tmp_path / "a.mcap", synthetic_messages())
    src = McapSource(tmp_path / "a.mcap")
    full = [m for m in src if not isinstance(m, Odometry)]
    lean = list(src.without_odometry())
    assert [(type(m), m.t_ns) for m in lean] == [(type(m), m.t_ns) for m in full] and len(lean) == 12
    for a, b in zip(full, lean, strict=True):
        if isinstance(a, RgbdFrame):
            assert np.array_equal(a.color, b.color) and a.index == b.index
