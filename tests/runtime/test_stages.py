from __future__ import annotations

import sys
import threading
import time

import pytest

from litevloc.runtime.service.queues import BoundedFifo
from litevloc.runtime.service.stages import (
    Periodic,
    Stage,
    StageInput,
    StageState,
    configure_threads,
    ort_session_options,
)


@pytest.mark.timeout(20)
def test_map_stage_processes_all_and_finishes_when_closed() -> None:
    stop = threading.Event()
    inq: BoundedFifo[int] = BoundedFifo("in", 1000)
    outq: BoundedFifo[int] = BoundedFifo("out", 1000)
    st = Stage.map("square", inq, lambda x: x * x if x % 2 == 0 else None, [outq], stop)
    st.start()
    for i in range(100):
        inq.put(i)
    inq.close()
    assert st.join(5.0)
    assert st.state == StageState.DONE and st.processed == 100
    assert [outq.get_nowait() for _ in range(50)] == [i * i for i in range(0, 100, 2)]
    lat = st.status()["latency"]["in"]
    assert lat["count"] == 100 and lat["p99_ms"] >= lat["median_ms"] >= 0


@pytest.mark.timeout(20)
def test_priority_input_drained_first() -> None:
    stop = threading.Event()
    hi: BoundedFifo[str] = BoundedFifo("hi", 100)
    lo: BoundedFifo[str] = BoundedFifo("lo", 100)
    seen: list[str] = []
    for i in range(3):
        hi.put(f"h{i}")
        lo.put(f"l{i}")
    st = Stage("fusion", [StageInput(hi, seen.append), StageInput(lo, seen.append)], stop)
    st.start()
    time.sleep(0.2)
    hi.close()
    lo.close()
    assert st.join(5.0)
    assert seen[:3] == ["h0", "h1", "h2"] and sorted(seen[3:]) == ["l0", "l1", "l2"]


@pytest.mark.timeout(20)
def test_a_closed_input_beside_an_open_empty_one_does_not_spin() -> None:
    stop = threading.Event()
    odom: BoundedFifo[int] = BoundedFifo("odom", 10)
    vloc: BoundedFifo[int] = BoundedFifo("vloc", 10)
    seen: list[int] = []
    st = Stage("fusion", [StageInput(odom, seen.append), StageInput(vloc, seen.append)], stop, wait_s=0.1)
    waits = 0
    wait = st.waker.wait

    def counted(timeout: float, ready: object) -> bool:
        nonlocal waits
        waits += 1
        return bool(wait(timeout, ready))  # type: ignore[arg-type]

    st.waker.wait = counted  # type: ignore[method-assign]
    st.start()
    odom.close()  # the source ended; VLoc results may still come
    time.sleep(0.5)
    assert waits < 20, waits  # ~5 waits of wait_s, not a busy loop
    vloc.put(7)
    time.sleep(0.2)
    assert seen == [7]
    vloc.close()
    assert st.join(5.0) and st.state == StageState.DONE


@pytest.mark.timeout(20)
def test_failure_is_reported_with_traceback() -> None:
    stop = threading.Event()
    inq: BoundedFifo[int] = BoundedFifo("in", 10)

    def boom(x: int) -> None:
        raise ZeroDivisionError(f"bad item {x}")

    st = Stage("vloc", [StageInput(inq, boom)], stop, on_error="fail")
    st.start()
    inq.put(3)
    assert st.failed.wait(5.0)
    assert st.join(5.0)
    s = st.status()
    assert s["state"] == "FAILED" and s["errors"] == 1 and not s["alive"]
    assert "ZeroDivisionError: bad item 3" in s["last_error"] and "in boom" in s["last_error"]


@pytest.mark.timeout(20)
def test_restart_policy_skips_items_until_limit() -> None:
    stop = threading.Event()
    inq: BoundedFifo[int] = BoundedFifo("in", 100)
    ok: list[int] = []

    def h(x: int) -> None:
        if x < 0:
            raise ValueError("negative")
        ok.append(x)

    st = Stage("s", [StageInput(inq, h)], stop, on_error="restart", max_restarts=2)
    st.start()
    for x in (1, -1, 2, -2, 3):
        inq.put(x)
    time.sleep(0.2)
    assert st.state == StageState.RUNNING and ok == [1, 2, 3] and st.errors == 2
    inq.put(-3)  # third error > max_restarts -> FAILED
    assert st.failed.wait(5.0) and st.join(5.0) and st.state == StageState.FAILED


@pytest.mark.timeout(20)
def test_stop_event_ends_blocked_stage_quickly() -> None:
    stop = threading.Event()
    st = Stage("idle", [StageInput(BoundedFifo("in", 10), lambda x: None)], stop, wait_s=10.0)
    st.start()
    time.sleep(0.05)
    t0 = time.monotonic()
    stop.set()
    st.wake()
    assert st.join(5.0) and time.monotonic() - t0 < 1.0 and st.state == StageState.STOPPED


@pytest.mark.timeout(20)
def test_periodic_ticks_and_final_call() -> None:
    stop = threading.Event()
    n = [0]

    def tick() -> None:
        n[0] += 1

    p = Periodic("status", tick, 0.02, stop)
    p.start()
    time.sleep(0.2)
    stop.set()
    assert p.join(2.0)
    assert 3 <= n[0] <= 15 and p.state == StageState.STOPPED


def test_thread_budget() -> None:
    import cv2

    old = sys.getswitchinterval()
    try:
        counts = configure_threads(cv_threads=2, ort_intra_op=2, ort_inter_op=1, switch_interval_s=0.001)
        assert sys.getswitchinterval() == pytest.approx(0.001)
    finally:
        sys.setswitchinterval(old)
    assert cv2.getNumThreads() == 2 and counts["ort_intra_op"] == 2
    so = ort_session_options()
    assert so.intra_op_num_threads == 2 and so.inter_op_num_threads == 1
    with pytest.raises(ValueError):
        configure_threads(cv_threads=0)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="per-thread nice is Linux-only")
def test_low_priority_threads_and_their_children() -> None:
    """The VLoc thread and the threads started by code run at low priority inherit its nice."""
    import os

    from litevloc.runtime.service.stages import call_in_low_priority_thread, lower_thread_priority

    def child_nice() -> tuple[int, int]:
        seen: list[int] = []
        t = threading.Thread(target=lambda: seen.append(os.getpriority(os.PRIO_PROCESS, threading.get_native_id())))
        t.start()
        t.join()
        return os.getpriority(os.PRIO_PROCESS, threading.get_native_id()), seen[0]

    base = os.getpriority(os.PRIO_PROCESS, threading.get_native_id())
    own, child = call_in_low_priority_thread(child_nice, max(base, 7))
    assert own == child == max(base, 7)
    assert os.getpriority(os.PRIO_PROCESS, threading.get_native_id()) == base  # the caller is untouched
    with pytest.raises(ZeroDivisionError):
        call_in_low_priority_thread(lambda: 1 / 0, 7)
    assert lower_thread_priority(0) is None

    stop = threading.Event()
    q: BoundedFifo[int] = BoundedFifo("q", 4)
    got: list[int] = []
    def handler(_item: int) -> None:
        got.append(os.getpriority(os.PRIO_PROCESS, threading.get_native_id()))

    stage = Stage("low", [StageInput(q, handler)], stop, nice=max(base, 9))
    stage.start()
    q.put(1)
    q.close()
    assert stage.join(5.0)
    assert got == [max(base, 9)] and stage.status()["nice"] == max(base, 9)


def test_realtime_priority_is_what_the_status_says() -> None:
    """A stage with `rt_priority` runs SCHED_FIFO where permitted (and threads it starts do not);
    where not permitted it keeps normal priority and says why. Either way the status is true."""
    import os

    from litevloc.runtime.service.stages import use_realtime_priority

    stop = threading.Event()
    q: BoundedFifo[int] = BoundedFifo("q", 4)
    seen: list[tuple[int, int]] = []

    def handler(_item: int) -> None:
        child: list[int] = []
        t = threading.Thread(target=lambda: child.append(os.sched_getscheduler(threading.get_native_id())))
        t.start()
        t.join()
        own = os.sched_getscheduler(threading.get_native_id()) & ~os.SCHED_RESET_ON_FORK
        seen.append((own, child[0]))

    stage = Stage("rt", [StageInput(q, handler)], stop, rt_priority=7)
    stage.start()
    q.put(1)
    q.close()
    assert stage.join(5.0)
    (own, child_policy), = seen
    text = stage.status()["scheduling"]
    if text == "SCHED_FIFO 7":
        assert own == os.SCHED_FIFO and child_policy == os.SCHED_OTHER  # reset on fork
    else:
        assert own == os.SCHED_OTHER and "not permitted" in text
    assert use_realtime_priority(0) == "normal"
    assert os.sched_getscheduler(threading.get_native_id()) == os.SCHED_OTHER  # the caller is untouched
