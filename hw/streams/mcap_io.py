"""MCAP recordings with ROS 2 message schemas (CDR, `ros2msg` schema encoding).

Topics (what Foxglove and `ros2 bag` see):

| topic                       | type                          | content                        |
|-----------------------------|-------------------------------|--------------------------------|
| /camera/color/image/compressed | sensor_msgs/CompressedImage | JPEG colour                    |
| /camera/depth/image         | sensor_msgs/Image (16UC1)     | depth in mm, 0 = invalid, registered to colour |
| /camera/color/camera_info   | sensor_msgs/CameraInfo        | K of the colour image          |
| /odom                       | nav_msgs/Odometry             | T_odom_base                    |
| /ground_truth/camera_pose   | geometry_msgs/PoseStamped     | T_world_camera (evaluation)    |

The parts of one RGB-D frame share the header stamp; a frame is emitted when its
colour, camera info and (if the recording has a depth channel) depth have all arrived.
Log time = header stamp, so `iter_messages(log_time_order=True)` replays in time order.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator
from pathlib import Path
from types import TracebackType
from typing import Any, BinaryIO

import numpy as np
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer
from numpy.typing import NDArray

from litevloc.hw import ros_msgs
from litevloc.hw.messages import (
    EncodedRgbdFrame,
    GroundTruthPose,
    Message,
    Odometry,
    RgbdFrame,
    SourceMessage,
    StreamError,
    StreamStats,
    decode_color,
    depth_from_millimetres,
    depth_to_millimetres,
)
from litevloc.hw.streams.base import select_indices

TOPIC_COLOR = "/camera/color/image/compressed"
TOPIC_DEPTH = "/camera/depth/image"
TOPIC_INFO = "/camera/color/camera_info"
TOPIC_ODOM = "/odom"
TOPIC_GT = "/ground_truth/camera_pose"

TOPIC_TYPES = {
    TOPIC_COLOR: ros_msgs.COMPRESSED_IMAGE,
    TOPIC_DEPTH: ros_msgs.IMAGE,
    TOPIC_INFO: ros_msgs.CAMERA_INFO,
    TOPIC_ODOM: ros_msgs.ODOMETRY,
    TOPIC_GT: ros_msgs.POSE_STAMPED,
}
_FRAME_TOPICS = (TOPIC_COLOR, TOPIC_DEPTH, TOPIC_INFO)
# What the mcap library (and zstd/lz4 below it) raise on a corrupt or truncated file: besides
# McapError, plain struct/zstd/overflow errors from length fields that point anywhere. All become
# StreamError.
_CORRUPT: tuple[type[BaseException], ...] = (McapError, ValueError, EOFError, KeyError, IndexError, OverflowError,
                                             struct.error, MemoryError, RuntimeError)
try:
    import zstandard

    _CORRUPT = (*_CORRUPT, zstandard.ZstdError)
except ImportError:  # pragma: no cover - mcap depends on zstandard
    pass
_CORRUPT_OR_OS: tuple[type[BaseException], ...] = (*_CORRUPT, OSError)


JPEG_QUALITY = 95  # of recorded colour frames


def encode_jpeg(color: NDArray[np.uint8], quality: int = JPEG_QUALITY, index: int = 0) -> bytes:
    """The JPEG bytes a recording stores for an (H, W, 3) RGB colour image (frame `index` names
    it in the StreamError if encoding fails)."""
    import cv2  # here: a reader (the replay's child process) loads no OpenCV

    ok, enc = cv2.imencode(".jpg", color[:, :, ::-1], [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise StreamError(f"frame {index}: JPEG encoding failed")
    return bytes(enc.tobytes())


class McapRecorder:
    """Write `Message`s to an MCAP file (zstd chunks). Use as a context manager."""

    def __init__(self, path: str | Path, jpeg_quality: int = JPEG_QUALITY,
                 metadata: dict[str, str] | None = None) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.jpeg_quality = int(jpeg_quality)
        self._fh: BinaryIO = open(self.path, "wb")  # noqa: SIM115 - closed in close()
        self._writer = Writer(self._fh, compression=CompressionType.ZSTD)
        self._writer.start(profile="ros2", library="litevloc")
        self._channels: dict[str, int] = {}
        self._seq: dict[str, int] = {}
        self.counts: dict[str, int] = {}
        if metadata:
            self._writer.add_metadata("litevloc", {str(k): str(v) for k, v in metadata.items()})

    def _channel(self, topic: str) -> int:
        if topic not in self._channels:
            typename = TOPIC_TYPES[topic]
            schema_id = self._writer.register_schema(
                name=typename, encoding="ros2msg", data=ros_msgs.msgdef(typename).encode()
            )
            self._channels[topic] = self._writer.register_channel(
                topic=topic, message_encoding="cdr", schema_id=schema_id
            )
        return self._channels[topic]

    def _put(self, topic: str, t_ns: int, msg: Any) -> None:
        self._put_cdr(topic, t_ns, ros_msgs.serialize(msg, TOPIC_TYPES[topic]))

    def _put_cdr(self, topic: str, t_ns: int, data: bytes) -> None:
        ch = self._channel(topic)
        seq = self._seq.get(topic, 0)
        self._seq[topic] = seq + 1
        self._writer.add_message(channel_id=ch, log_time=t_ns, publish_time=t_ns, sequence=seq, data=data)
        self.counts[topic] = self.counts.get(topic, 0) + 1

    def write(self, msg: Message) -> None:
        """Append one message (frames write camera_info, depth, then colour)."""
        if isinstance(msg, RgbdFrame):
            h, w = msg.color.shape[:2]
            self._put(TOPIC_INFO, msg.t_ns, ros_msgs.camera_info_msg(msg.t_ns, msg.K, w, h, msg.frame_id))
            if msg.depth is not None:
                if msg.depth.shape != (h, w):
                    raise StreamError(f"frame {msg.index}: depth {msg.depth.shape} does not match colour {(h, w)}")
                depth_msg = ros_msgs.depth_image_msg(msg.t_ns, depth_to_millimetres(msg.depth), msg.frame_id)
                self._put(TOPIC_DEPTH, msg.t_ns, depth_msg)
            jpeg = msg.color_jpeg
            if jpeg is None:
                jpeg = encode_jpeg(msg.color, self.jpeg_quality, msg.index)
            self._put(TOPIC_COLOR, msg.t_ns, ros_msgs.compressed_image_msg(msg.t_ns, jpeg, "jpeg", msg.frame_id))
        elif isinstance(msg, Odometry):  # packed directly: a 200 Hz topic (same bytes as rosbags')
            self._put_cdr(TOPIC_ODOM, msg.t_ns, ros_msgs.odometry_cdr(msg.t_ns, msg.T_odom_base, msg.frame_id,
                                                                     msg.child_frame_id, msg.covariance))
        elif isinstance(msg, GroundTruthPose):
            self._put(TOPIC_GT, msg.t_ns, ros_msgs.pose_stamped_msg(msg.t_ns, msg.T_world_camera, msg.frame_id))
        else:  # pragma: no cover - Message is a closed union
            raise TypeError(f"cannot record {type(msg).__name__}")

    def close(self) -> None:
        if not self._fh.closed:
            self._writer.finish()
            self._fh.close()

    def __enter__(self) -> McapRecorder:
        return self

    def __exit__(self, et: type[BaseException] | None, ev: BaseException | None, tb: TracebackType | None) -> None:
        self.close()


def record_messages(
    messages: Iterator[Message] | Any, path: str | Path, metadata: dict[str, str] | None = None,
    on_frame: Any = None,
) -> dict[str, int]:
    """Write every message to `path` atomically (a `.partial` file renamed at the end).

    Returns counts of frames, odometry and ground-truth messages; `on_frame()` is called per frame.
    """
    dst = Path(path)
    tmp = dst.with_suffix(".mcap.partial")
    counts = {"frames": 0, "odometry": 0, "ground_truth": 0}
    try:
        with McapRecorder(tmp, metadata=metadata) as rec:
            for msg in messages:
                rec.write(msg)
                if isinstance(msg, RgbdFrame):
                    counts["frames"] += 1
                    if on_frame is not None:
                        on_frame()
                elif isinstance(msg, Odometry):
                    counts["odometry"] += 1
                elif isinstance(msg, GroundTruthPose):
                    counts["ground_truth"] += 1
        tmp.replace(dst)
    finally:
        tmp.unlink(missing_ok=True)
    return counts


class McapSource:
    """Replay an MCAP recording as `Message`s.

    `strict=True` (offline tools): any malformed message or time going backwards raises
    `StreamError` naming the file, topic and time. `strict=False` (live/replay into a
    running service): such messages are counted in `stats.skipped` and dropped.
    `messages(defer_color=True)` (the service's source, and the SLAM's in `map build`): frames
    come as `EncodedRgbdFrame`, their colour decoded by whoever takes them (`decode()`), so
    frames a consumer drops are never decompressed; a colour that does not decode then raises
    StreamError at `decode()` (strict: the consumer stops) or is the consumer's to count.
    """

    def __init__(self, path: str | Path, frames: slice = slice(None), strict: bool = True) -> None:
        self.path = Path(path)
        self.name = f"mcap:{self.path.name}"
        self.stats = StreamStats()
        self.strict = strict
        if not self.path.is_file():
            raise StreamError(f"recording not found: {self.path}")
        try:
            with open(self.path, "rb") as fh:
                summary = make_reader(fh).get_summary()
        except _CORRUPT_OR_OS as exc:
            raise StreamError(f"{self.path}: not a readable MCAP file: {exc}") from exc
        if summary is None or summary.statistics is None:
            raise StreamError(f"{self.path}: MCAP file has no summary/statistics (truncated or unfinished recording?)")
        self.topics = {ch.topic: ch.id for ch in summary.channels.values()}
        counts = summary.statistics.channel_message_counts
        self.topic_counts = {ch.topic: int(counts.get(ch.id, 0)) for ch in summary.channels.values()}
        self.start_ns = int(summary.statistics.message_start_time)
        self.end_ns = int(summary.statistics.message_end_time)
        self.has_depth = TOPIC_DEPTH in self.topics
        n_frames = self.topic_counts.get(TOPIC_COLOR, 0)
        self._frames = frames
        self._selected = select_indices(n_frames, frames)
        self._window: tuple[int, int] | None = None
        if frames != slice(None) and self._selected:
            stamps = self._color_stamps()
            self._window = (stamps[self._selected[0]], stamps[self._selected[-1]])

    @property
    def frames(self) -> slice:
        """The frame selection this source was opened with (`--frames`)."""
        return self._frames

    def frame_count(self) -> int:
        return len(self._selected)

    def duration_s(self) -> float:
        return (self.end_ns - self.start_ns) * 1e-9

    def _color_stamps(self) -> list[int]:
        with open(self.path, "rb") as fh:
            try:
                it = make_reader(fh).iter_messages(topics=[TOPIC_COLOR], log_time_order=True)
                return [m.log_time for _, _, m in it]
            except _CORRUPT as exc:
                raise StreamError(f"{self.path}: corrupt MCAP data: {exc}") from exc

    def _fail(self, reason: str, detail: str) -> None:
        if self.strict:
            raise StreamError(f"{self.path}: {reason}: {detail}")
        self.stats.skip(reason)

    def __iter__(self) -> Iterator[Message]:
        for m in self._read(defer_color=False):
            assert not isinstance(m, EncodedRgbdFrame)  # only yielded when deferring
            yield m

    def messages(self, defer_color: bool = False, skip_odometry: bool = False) -> Iterator[SourceMessage]:
        """The recording's messages; with `defer_color`, frames as `EncodedRgbdFrame` (the
        colour is checked where it is decoded, the rest as `strict` says); `skip_odometry`:
        /odom skipped undecoded (see `without_odometry`)."""
        return self._read(defer_color, skip_odometry)

    def without_odometry(self) -> Iterator[Message]:
        """The messages as iterating gives them, /odom skipped undecoded: a map posed by
        ground truth never reads the 200 Hz odometry, which was most of its reading time."""
        for m in self._read(defer_color=False, skip_odometry=True):
            assert not isinstance(m, EncodedRgbdFrame)  # only yielded when deferring
            yield m

    def _read(self, defer_color: bool, skip_odometry: bool = False) -> Iterator[SourceMessage]:
        selected = set(self._selected)
        pending: dict[int, dict[str, Any]] = {}
        frame_counter = 0
        last_t: dict[str, int] = {}
        lo, hi = self._window if self._window else (None, None)
        with open(self.path, "rb") as fh:
            reader = make_reader(fh, validate_crcs=True)  # a flipped bit is an error, not wrong data (fuzzing)
            it = reader.iter_messages(log_time_order=True)
            n_raw = 0
            while True:
                try:
                    item = next(it)
                except StopIteration:
                    break
                except _CORRUPT as exc:
                    raise StreamError(f"{self.path}: corrupt MCAP data: {exc}") from exc
                _, channel, raw = item
                n_raw += 1
                topic = channel.topic
                if topic not in TOPIC_TYPES:
                    self.stats.skip(f"unknown topic {topic}")
                    continue
                if skip_odometry and topic == TOPIC_ODOM:
                    continue
                try:
                    msg = ros_msgs.deserialize(raw.data, TOPIC_TYPES[topic])
                    t_ns = ros_msgs.stamp_ns(msg.header)
                except ros_msgs.MessageDecodeError as exc:
                    self._fail(f"undecodable {topic} message", str(exc))
                    continue
                key = "frame" if topic in _FRAME_TOPICS else topic
                if topic != TOPIC_DEPTH and topic != TOPIC_INFO and t_ns < last_t.get(key, -1):
                    self._fail(f"timestamps go backwards on {topic}", f"{t_ns} ns after {last_t[key]} ns")
                    continue
                last_t[key] = max(t_ns, last_t.get(key, -1))
                if topic in _FRAME_TOPICS:
                    parts = pending.setdefault(t_ns, {})
                    parts[topic] = msg
                    if topic == TOPIC_COLOR:
                        parts["index"] = frame_counter
                        frame_counter += 1
                    if TOPIC_COLOR in parts and TOPIC_INFO in parts and (TOPIC_DEPTH in parts or not self.has_depth):
                        del pending[t_ns]
                        if parts["index"] in selected:
                            frame = self._make_frame(t_ns, parts, defer_color)
                            if frame is not None:
                                self.stats.messages += 1
                                yield frame
                    continue
                if lo is not None and hi is not None and not (lo <= t_ns <= hi):
                    continue
                out = self._make_other(topic, t_ns, msg)
                if out is not None:
                    self.stats.messages += 1
                    yield out
        expected = sum(self.topic_counts.values())
        if n_raw != expected:  # e.g. a zeroed chunk index: the reader would otherwise just yield less
            self._fail("messages missing or extra", f"the summary lists {expected} messages, {n_raw} were readable")
        for t_ns, parts in pending.items():
            if parts.get("index") in selected or TOPIC_COLOR not in parts:
                self._fail("incomplete frame (missing colour, depth or camera_info)", f"stamp {t_ns}")

    def _make_frame(self, t_ns: int, parts: dict[str, Any], defer_color: bool = False
                    ) -> RgbdFrame | EncodedRgbdFrame | None:
        try:
            cmsg = parts[TOPIC_COLOR]
            jpeg = bytes(np.asarray(cmsg.data, dtype=np.uint8).tobytes())
            is_jpeg = cmsg.format.lower().startswith(("jpeg", "jpg"))
            K = ros_msgs.camera_info_K(parts[TOPIC_INFO])
            if defer_color:
                mm_d = ros_msgs.depth_image_to_mm(parts[TOPIC_DEPTH]) if TOPIC_DEPTH in parts else None
                return EncodedRgbdFrame(
                    t_ns=t_ns, color_data=jpeg, depth=None if mm_d is None else depth_from_millimetres(mm_d), K=K,
                    index=int(parts["index"]), frame_id=cmsg.header.frame_id or "camera", is_jpeg=is_jpeg,
                    where=f"{self.path} colour at {t_ns} ns")
            color = decode_color(jpeg, f"{self.path} colour at {t_ns} ns")
            depth = None
            if TOPIC_DEPTH in parts:
                mm = ros_msgs.depth_image_to_mm(parts[TOPIC_DEPTH])
                if mm.shape != color.shape[:2]:
                    raise StreamError(
                        f"depth {mm.shape[1]}x{mm.shape[0]} does not match colour "
                        f"{color.shape[1]}x{color.shape[0]} at {t_ns} ns"
                    )
                depth = depth_from_millimetres(mm)
        except (StreamError, ros_msgs.MessageDecodeError) as exc:
            self._fail("bad frame", str(exc))
            return None
        return RgbdFrame(
            t_ns=t_ns, color=color, depth=depth, K=K, index=int(parts["index"]),
            frame_id=cmsg.header.frame_id or "camera",
            color_jpeg=jpeg if is_jpeg else None,
        )

    def _make_other(self, topic: str, t_ns: int, msg: Any) -> Message | None:
        try:
            if topic == TOPIC_ODOM:
                t, T, cov = ros_msgs.odometry_to_matrix(msg)
                return Odometry(t, T, cov, frame_id=msg.header.frame_id, child_frame_id=msg.child_frame_id)
            if topic == TOPIC_GT:
                return GroundTruthPose(t_ns, ros_msgs.pose_to_matrix(msg.pose), frame_id=msg.header.frame_id)
        except ros_msgs.MessageDecodeError as exc:
            self._fail(f"bad {topic} message", str(exc))
        return None
