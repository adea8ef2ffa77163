"""Recordings and wire payloads: truncated / garbled MCAP files and messages, random CDR on the
odometry input. Only StreamError (strict) or counted skips (live) may come out."""

from __future__ import annotations

import contextlib
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from litevloc.base.geometry import make_T, so3_exp
from litevloc.hw import ros_msgs
from litevloc.hw.messages import GroundTruthPose, Odometry, RgbdFrame, StreamError
from litevloc.hw.odometry import OdometryChecker, encode_odometry
from litevloc.hw.streams.mcap_io import _FRAME_TOPICS, TOPIC_GT, TOPIC_ODOM, TOPIC_TYPES, McapRecorder, McapSource

K = np.array([[30.0, 0, 16], [0, 30.0, 12], [0, 0, 1]])


def _messages() -> list[Any]:
    rng = np.random.default_rng(0)
    out: list[Any] = []
    for i in range(20):
        t = 1_000_000 + i * 10_000_000
        T = make_T(so3_exp(np.array([0, 0, 0.01 * i])), np.array([0.01 * i, 0, 0]))
        out.append(Odometry(t, T))
        if i % 5 == 0:
            color = rng.integers(0, 255, (24, 32, 3), dtype=np.uint8)
            out.append(RgbdFrame(t, color, np.full((24, 32), 1.5, np.float32), K, index=i // 5))
            out.append(GroundTruthPose(t, T))
    return out


@pytest.fixture(scope="module")
def good_rec(tmp_path_factory: pytest.TempPathFactory) -> bytes:
    p = tmp_path_factory.mktemp("rec") / "r.mcap"
    with McapRecorder(p) as rec:
        for m in _messages():
            rec.write(m)
    n = sum(1 for _ in McapSource(p))
    assert n == len(_messages())
    return p.read_bytes()


def _read_all(p: Path, strict: bool) -> tuple[int, int]:
    src = McapSource(p, strict=strict)
    n = 0
    for m in src:
        n += 1
        if isinstance(m, RgbdFrame):  # whatever decodes is well-formed
            assert m.color.dtype == np.uint8 and m.color.ndim == 3 and m.color.shape[2] == 3
            assert m.depth is None or m.depth.shape == m.color.shape[:2]
        elif isinstance(m, Odometry):
            assert np.all(np.isfinite(m.T_odom_base))
    return n, src.stats.total_skipped


@settings(max_examples=120)
@given(data=st.data())
def test_corrupted_recording(good_rec: bytes, tmp_path: Path, count_case: Any, data: st.DataObject) -> None:
    count_case()
    raw = bytearray(good_rec)
    op = data.draw(st.sampled_from(["truncate", "flip", "flip_many", "zero_block"]))
    if op == "truncate":
        raw = raw[: data.draw(st.integers(0, len(raw) - 1))]
    elif op == "flip":
        i = data.draw(st.integers(0, len(raw) - 1))
        raw[i] ^= data.draw(st.integers(1, 255))
    elif op == "flip_many":
        for i in data.draw(st.lists(st.integers(0, len(raw) - 1), min_size=2, max_size=20)):
            raw[i] ^= 0x5A
    else:
        a, n = data.draw(st.integers(0, len(raw) - 1)), data.draw(st.integers(1, 256))
        raw[a: a + n] = bytes(len(raw[a: a + n]))
    p = tmp_path / f"c{len(raw)}_{hash(bytes(raw)) & 0xffff}.mcap"
    p.write_bytes(bytes(raw))
    try:
        got = list(McapSource(p, strict=True))
    except StreamError:
        got = None
    if got is not None:  # read without complaint: then it must be the recorded data, not something else
        want = _messages()
        assert len(got) == len(want)
        for a, b in zip(got, want, strict=True):
            assert type(a) is type(b) and a.t_ns == b.t_ns
            if isinstance(a, Odometry):
                assert np.allclose(a.T_odom_base, b.T_odom_base)
            if isinstance(a, RgbdFrame):
                assert np.allclose(a.depth, b.depth) and np.allclose(a.K, b.K)
    with contextlib.suppress(StreamError):
        _read_all(p, strict=False)


CHANNEL_TOPICS = sorted(TOPIC_TYPES)


@settings(max_examples=100)
@given(data=st.data())
def test_garbled_messages_in_a_valid_file(tmp_path: Path, count_case: Any, data: st.DataObject) -> None:
    """A well-formed MCAP whose message payloads are garbled: strict -> StreamError, live -> counted skip."""
    count_case()
    p = tmp_path / "g.mcap"
    msgs = _messages()
    bad_topic = data.draw(st.sampled_from(CHANNEL_TOPICS))
    garble = data.draw(st.sampled_from(["random", "truncate", "flip"]))
    with McapRecorder(p) as rec:
        real_put = rec._put

        def put(topic: str, t_ns: int, msg: Any) -> None:
            if topic != bad_topic:
                real_put(topic, t_ns, msg)
                return
            payload = ros_msgs.serialize(msg, TOPIC_TYPES[topic])
            if garble == "random":
                payload = data.draw(st.binary(max_size=64))
            elif garble == "truncate":
                payload = payload[: data.draw(st.integers(0, max(0, len(payload) - 1)))]
            else:
                b = bytearray(payload)
                b[data.draw(st.integers(0, len(b) - 1))] ^= data.draw(st.integers(1, 255))
                payload = bytes(b)
            ch = rec._channel(topic)
            rec._writer.add_message(channel_id=ch, log_time=t_ns, publish_time=t_ns, sequence=0, data=payload)

        rec._put = put
        for m in msgs[:12]:
            rec.write(m)
    written = msgs[:12]
    # messages the garbled topic can spoil: an RGB-D frame is made of three topics
    topics = {Odometry: {TOPIC_ODOM}, GroundTruthPose: {TOPIC_GT}, RgbdFrame: set(_FRAME_TOPICS)}
    spoilable = sum(1 for m in written if bad_topic in topics[type(m)])
    assert spoilable > 0
    try:
        strict: tuple[int, int] | None = _read_all(p, strict=True)
    except StreamError as exc:
        strict = None
        assert str(exc)  # a message for the user
    n_live, skipped = _read_all(p, strict=False)  # live: never raises for bad messages
    assert len(written) - spoilable <= n_live <= len(written)  # nothing unaffected is lost
    if skipped:  # live dropped what it could not decode, so strict must have refused the file
        assert strict is None and n_live < len(written)
    else:  # the garbled payload still decoded (e.g. a flipped bit in a float): both read everything
        assert n_live == len(written) and strict == (len(written), 0)


def _valid_payload(t: int) -> bytes:
    return encode_odometry(Odometry(t, make_T(so3_exp(np.array([0.1, 0.2, 0.3])), np.array([1.0, 2.0, 3.0])),
                                    np.eye(6) * 0.01))


@settings(max_examples=300)
@given(st.binary(max_size=400))
def test_random_cdr_on_odometry_input(count_case: Any, payload: bytes) -> None:
    count_case()
    chk = OdometryChecker()
    out = chk.check_payload(payload)
    r = chk.report()
    assert r["received"] == 1
    if out is None:
        assert r["skipped_total"] == 1
    else:
        R = out.T_odom_base[:3, :3]
        assert np.all(np.isfinite(out.T_odom_base)) and np.allclose(R.T @ R, np.eye(3), atol=1e-6)


@settings(max_examples=300)
@given(st.data())
def test_mutated_odometry_cdr(count_case: Any, data: st.DataObject) -> None:
    count_case()
    chk = OdometryChecker()
    assert chk.check_payload(_valid_payload(5_000_000_000)) is not None
    b = bytearray(_valid_payload(5_000_000_000 + 5_000_000))
    for _ in range(data.draw(st.integers(1, 4))):
        b[data.draw(st.integers(0, len(b) - 1))] = data.draw(st.integers(0, 255))
    if data.draw(st.booleans()):
        b = b[: data.draw(st.integers(0, len(b)))]
    out = chk.check_payload(bytes(b))
    r = chk.report()
    assert r["received"] == 2 and r["accepted"] + r["skipped_total"] == 2
    if out is not None:
        assert out.t_ns > 5_000_000_000 and np.all(np.isfinite(out.T_odom_base))
        R = out.T_odom_base[:3, :3]
        assert np.allclose(R.T @ R, np.eye(3), atol=1e-6)


@pytest.mark.timeout(30)
def test_garbage_over_zenoh_is_counted_not_fatal(count_case: Any) -> None:
    """Random payloads published on the odometry key of a live session: counted, and valid
    odometry afterwards still goes through."""
    from litevloc.config.schema import ZenohConfig
    from litevloc.hw.odometry import OdometryReceiver
    from litevloc.runtime.transport.bus import Bus
    from tests.runtime.zenoh_helpers import free_port

    ep = f"tcp/127.0.0.1:{free_port()}"
    got: list[Odometry] = []
    rng = np.random.default_rng(1)
    with Bus(ZenohConfig(listen=(ep,))) as a, Bus(ZenohConfig(listen=(), connect=(ep,))) as b:
        rx = OdometryReceiver(a.session, "odom", got.append)
        time.sleep(0.3)
        pub = b.session.declare_publisher("odom")
        for i in range(200):
            count_case()
            pub.put(rng.bytes(int(rng.integers(0, 300))) if i % 2 else _valid_payload(10**9 + i)[: int(rng.integers(0,
                                                                                                               40))])
        pub.put(_valid_payload(2 * 10**9))
        t_end = time.monotonic() + 5
        while time.monotonic() < t_end and rx.report()["received"] < 201:
            time.sleep(0.05)
        r = rx.report()
        rx.close()
    assert r["received"] == 201 and r["skipped_total"] == 200 and len(got) == 1
