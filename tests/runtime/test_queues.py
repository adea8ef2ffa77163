from __future__ import annotations

import threading
import time

import pytest

from litevloc.runtime.service.queues import (
    BoundedFifo,
    LatestMailbox,
    QueueClosed,
    QueueEmpty,
    QueueOverflow,
)


def test_fifo_order_metrics_and_close() -> None:
    q: BoundedFifo[int] = BoundedFifo("odom", capacity=4)
    for i in range(3):
        q.put(i)
    time.sleep(0.002)
    m = q.metrics()
    assert (m.depth, m.high_water, m.puts, m.gets, m.drops, m.overflows) == (3, 3, 3, 0, 0, 0)
    assert m.age_oldest_ms >= m.age_newest_ms >= 1.0
    assert [q.get(0.1) for _ in range(3)] == [0, 1, 2]
    assert q.metrics().wait_ms["count"] == 3 and q.metrics().wait_ms["median_ms"] >= 1.0
    with pytest.raises(QueueEmpty):
        q.get(0.01)
    q.put(7)
    q.close()
    with pytest.raises(QueueClosed):
        q.put(8)
    assert q.get(0.1) == 7  # drained after close
    with pytest.raises(QueueClosed):
        q.get(0.1)


def test_fifo_overflow_records_but_never_drops() -> None:
    q: BoundedFifo[int] = BoundedFifo("odom", capacity=2)
    for i in range(5):
        q.put(i)
    m = q.metrics()
    assert m.overflows == 3 and m.depth == 5 and m.error is not None and "overflowed 3 times" in m.error
    assert [q.get_nowait() for _ in range(5)] == list(range(5))


def test_fifo_overflow_raise_refuses_item() -> None:
    q: BoundedFifo[int] = BoundedFifo("results", capacity=1, overflow="raise")
    q.put(1)
    with pytest.raises(QueueOverflow, match="full"):
        q.put(2)
    assert len(q) == 1 and q.metrics().overflows == 1
    with pytest.raises(ValueError):
        BoundedFifo("x", capacity=0)


def test_mailbox_keeps_latest_and_counts_drops() -> None:
    mb: LatestMailbox[int] = LatestMailbox("frames")
    for i in range(5):
        mb.put(i)
    assert mb.metrics().drops == 4  # 0..3 replaced, 4 still in the slot
    assert mb.get(0.1) == 4
    mb.put(5)
    assert mb.get(0.1) == 5
    m = mb.metrics()
    assert (m.puts, m.gets, m.drops, m.depth) == (6, 2, 4, 0)


def test_blocking_get_wakes_on_put() -> None:
    q: BoundedFifo[int] = BoundedFifo("x", capacity=10)
    out: list[int] = []

    def consumer() -> None:
        out.append(q.get(5.0))

    th = threading.Thread(target=consumer)
    th.start()
    time.sleep(0.05)
    t0 = time.monotonic()
    q.put(42)
    th.join(5.0)
    assert out == [42] and time.monotonic() - t0 < 1.0


@pytest.mark.timeout(30)
@pytest.mark.parametrize("producers", [1, 3])
def test_fifo_stress_no_loss_in_order(producers: int) -> None:
    n = 20_000
    q: BoundedFifo[tuple[int, int]] = BoundedFifo("stress", capacity=1_000_000)
    got: list[tuple[int, int]] = []

    def produce(pid: int) -> None:
        for i in range(n):
            q.put((pid, i))
            if i % 1000 == 0:
                time.sleep(0)

    def consume() -> None:
        while True:
            try:
                got.append(q.get(5.0))
            except QueueClosed:
                return

    c = threading.Thread(target=consume)
    c.start()
    ps = [threading.Thread(target=produce, args=(p,)) for p in range(producers)]
    for p in ps:
        p.start()
    for p in ps:
        p.join(20)
    q.close()
    c.join(20)
    assert not c.is_alive()
    assert len(got) == n * producers and q.metrics().gets == n * producers
    for pid in range(producers):  # per-producer order preserved
        seq = [i for p, i in got if p == pid]
        assert seq == list(range(n))


@pytest.mark.timeout(30)
def test_mailbox_stress_drops_accounted_and_monotonic() -> None:
    n = 20_000
    mb: LatestMailbox[int] = LatestMailbox("frames")
    got: list[int] = []
    done = threading.Event()

    def consume() -> None:
        while True:
            try:
                got.append(mb.get(5.0))
            except QueueClosed:
                return
            if len(got) % 50 == 0:
                time.sleep(0.0005)  # a slow consumer

    c = threading.Thread(target=consume)
    c.start()
    for i in range(n):
        mb.put(i)
    done.set()
    mb.close()
    c.join(20)
    assert not c.is_alive()
    assert got == sorted(got) and len(set(got)) == len(got)  # never reordered or duplicated
    assert got[-1] == n - 1  # the latest value is never lost
    m = mb.metrics()
    assert m.drops == n - len(got) and m.drops > 0 and m.gets == len(got)
