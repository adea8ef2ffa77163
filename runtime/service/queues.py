"""Queues between runtime stages, without a lock on the hot path.

CPython's `collections.deque.append` and `popleft` are atomic (they run under the GIL
without releasing it), so a put is one `append` and a get one `popleft`; no mutex is
taken per message. A `threading.Event` is touched only when a consumer is actually
blocked (the `Waker` protocol below), so a busy pipeline never pays for it.

* `LatestMailbox[T]`: a latest-value slot (`deque(maxlen=1)`). A put replaces an
  unread value; the consumer counts the values it never saw from sequence-number gaps,
  so `drops` is exact without any shared counter. Single consumer.
* `BoundedFifo[T]`: never drops. A put beyond `capacity` is an overflow: with
  `overflow="record"` (default, for odometry) the item is still enqueued and the
  overflow is counted and reported as an error in `metrics()`; with `overflow="raise"`
  the put raises `QueueOverflow` and the item is not enqueued (the caller owns it).
  `capacity` is exact with one producer; several producers may overshoot it by at most
  one item each (the check and the append are two atomic steps).
* `DropQueue`: the live view's bounded queue, off the hot path: a put never blocks and
  drops the oldest item when full; a lock keeps the drop count exact. Any producer, one
  consumer taking everything queued at once.

Metrics of the first two (`QueueMetrics`): depth, high-water mark, puts, gets, drops,
overflows, and message age in ms = now - enqueue time of the oldest / newest queued item (queue wait,
on the `metrics.now_ns` monotonic clock; independent of sensor stamps, which may come
from a recording), plus a sliding window of the wait time of consumed items.

`close()` marks the end of the stream: consumers drain what is left, then `get`
raises `QueueClosed`. Puts after close raise `QueueClosed`.
"""

from __future__ import annotations

import threading
from collections import deque
from dataclasses import asdict, dataclass
from typing import Any, Generic, Literal, TypeVar

from litevloc.base.errors import LiteVLocError
from litevloc.runtime.metrics import LatencyWindow, now_ns

T = TypeVar("T")


class QueueClosed(Exception):
    """The queue was closed and (for `get`) is empty: no more items will come."""


class QueueOverflow(LiteVLocError, RuntimeError):
    """A `BoundedFifo` with overflow="raise" is full; the item was not enqueued."""


class QueueEmpty(Exception):
    """`get` timed out with no item."""


class Waker:
    """Wakes one blocked consumer; shared by all the queues a stage reads.

    Protocol (lock-free for producers while nobody waits): the consumer sets
    `waiting`, clears the event, re-checks its queues, and only then waits; a producer
    appends first and sets the event only if `waiting` is set. Under the GIL's sequential
    consistency either the producer sees `waiting` or the consumer's re-check sees the item.
    """

    def __init__(self) -> None:
        self._event = threading.Event()
        self.waiting = False

    def notify(self) -> None:
        if self.waiting:
            self._event.set()

    def wake(self) -> None:
        """Unconditional wake-up (close, stop)."""
        self._event.set()

    def wait(self, timeout: float, ready: Any) -> None:
        """Block up to `timeout` s unless `ready()` is already true after arming."""
        self.waiting = True
        self._event.clear()
        try:
            if ready():
                return
            self._event.wait(timeout)
        finally:
            self.waiting = False


@dataclass(frozen=True)
class QueueMetrics:
    name: str
    kind: str
    depth: int
    high_water: int
    capacity: int
    puts: int
    gets: int
    drops: int
    overflows: int
    closed: bool
    age_oldest_ms: float  # now - enqueue time of the oldest queued item; NaN when empty
    age_newest_ms: float
    wait_ms: dict[str, Any]  # enqueue -> dequeue time of consumed items (window summary)
    error: str | None = None

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


class QueueBase(Generic[T]):
    kind = "queue"

    def __init__(self, name: str, capacity: int, window: int = 1024) -> None:
        if capacity < 1:
            raise ValueError(f"queue {name!r}: capacity must be >= 1, got {capacity}")
        self.name = name
        self.capacity = capacity
        self._dq: deque[tuple[T, int, int]] = deque(maxlen=self._maxlen())
        self.waker = Waker()
        self.closed = False
        self.puts = 0  # written by the producer only
        self.gets = 0  # written by the consumer only
        self.high_water = 0
        self.wait = LatencyWindow(window)

    def _maxlen(self) -> int | None:
        return None

    def put(self, item: T) -> None:
        """Enqueue `item` (each queue kind says what happens when it is full)."""
        raise NotImplementedError

    def attach(self, waker: Waker) -> None:
        """Make this queue wake `waker` (a stage reading several queues shares one)."""
        self.waker = waker

    def __len__(self) -> int:
        return len(self._dq)

    def _append(self, item: T) -> None:
        if self.closed:
            raise QueueClosed(f"queue {self.name!r} is closed")
        seq = self.puts + 1
        self._dq.append((item, now_ns(), seq))
        self.puts = seq  # after the append: a reader never counts an item not yet queued
        n = len(self._dq)
        if n > self.high_water:
            self.high_water = n
        self.waker.notify()

    def _taken(self, entry: tuple[T, int, int]) -> T:
        self.gets += 1
        self.wait.add((now_ns() - entry[1]) * 1e-6)
        return entry[0]

    def get_nowait(self) -> T:
        """Pop the next item; QueueEmpty if none (QueueClosed if closed and drained)."""
        try:
            entry = self._dq.popleft()
        except IndexError:
            if self.closed and not self._dq:
                raise QueueClosed(f"queue {self.name!r} is closed") from None
            raise QueueEmpty(self.name) from None
        return self._taken(entry)

    def get(self, timeout: float) -> T:
        """Pop the next item, blocking up to `timeout` s (QueueEmpty), QueueClosed at the end."""
        deadline = now_ns() + int(timeout * 1e9)
        while True:
            try:
                return self.get_nowait()
            except QueueEmpty:
                pass
            remaining = (deadline - now_ns()) * 1e-9
            if remaining <= 0:
                raise QueueEmpty(self.name)
            self.waker.wait(remaining, self.ready)

    def ready(self) -> bool:
        """True if a get would not block (an item is queued, or the queue is closed)."""
        return bool(self._dq) or self.closed

    def close(self) -> None:
        self.closed = True
        self.waker.wake()

    def _ages(self) -> tuple[float, float]:
        nan = float("nan")
        t = now_ns()
        try:
            oldest = (t - self._dq[0][1]) * 1e-6
        except IndexError:
            return nan, nan
        try:
            newest = (t - self._dq[-1][1]) * 1e-6
        except IndexError:
            newest = nan
        return oldest, newest

    def drops(self) -> int:
        return 0

    def overflows(self) -> int:
        return 0

    def error(self) -> str | None:
        return None

    def metrics(self) -> QueueMetrics:
        oldest, newest = self._ages()
        return QueueMetrics(
            name=self.name, kind=self.kind, depth=len(self._dq), high_water=self.high_water,
            capacity=self.capacity, puts=self.puts, gets=self.gets, drops=self.drops(),
            overflows=self.overflows(), closed=self.closed, age_oldest_ms=oldest, age_newest_ms=newest,
            wait_ms=self.wait.summary(), error=self.error(),
        )


class LatestMailbox(QueueBase[T]):
    """Latest-value slot: `put` replaces an unread value (counted as a drop by the consumer)."""

    kind = "latest"

    def __init__(self, name: str, window: int = 1024) -> None:
        super().__init__(name, 1, window)
        self._last_seq = 0  # consumer side
        self._dropped = 0  # consumer side

    def _maxlen(self) -> int | None:
        return 1

    def put(self, item: T) -> None:
        self._append(item)

    def _taken(self, entry: tuple[T, int, int]) -> T:
        seq = entry[2]
        self._dropped += seq - self._last_seq - 1
        self._last_seq = seq
        return super()._taken(entry)

    def drops(self) -> int:
        """Values replaced before the consumer took them (exact once the consumer caught up;
        a value still in the slot is not a drop)."""
        in_slot = len(self._dq)
        # values put but neither taken nor still waiting: gaps seen so far, plus gaps
        # behind the value now in the slot (it will reveal them when taken).
        return max(self._dropped, self.puts - self.gets - in_slot)


class BoundedFifo(QueueBase[T]):
    """FIFO that never drops; beyond `capacity` it records (default) or raises an overflow."""

    kind = "fifo"

    def __init__(
        self, name: str, capacity: int, overflow: Literal["record", "raise"] = "record", window: int = 1024
    ) -> None:
        if overflow not in ("record", "raise"):
            raise ValueError(f"queue {name!r}: overflow must be 'record' or 'raise', got {overflow!r}")
        super().__init__(name, capacity, window)
        self.overflow = overflow
        self._overflows = 0
        self._first_overflow_ns: int | None = None

    def put(self, item: T) -> None:
        """Enqueue; on overflow count it (and raise QueueOverflow if overflow="raise")."""
        if len(self._dq) >= self.capacity:
            self._overflows += 1
            if self._first_overflow_ns is None:
                self._first_overflow_ns = now_ns()
            if self.overflow == "raise":
                raise QueueOverflow(
                    f"queue {self.name!r} is full ({self.capacity} items): the consumer is not keeping up"
                )
        self._append(item)

    def overflows(self) -> int:
        return self._overflows

    def error(self) -> str | None:
        if self._overflows == 0:
            return None
        return (
            f"queue {self.name!r} overflowed {self._overflows} times (capacity {self.capacity}, "
            f"high-water {self.high_water}): the consumer is not keeping up"
            + ("" if self.overflow == "record" else "; overflowing items were refused")
        )


class DropQueue:
    """Bounded FIFO that never blocks the producer: when full, the oldest item is dropped (counted).

    Any thread may `put`; one consumer thread `get`s. A lock guards the deque (uncontended:
    well under a microsecond) so the drop count is exact."""

    def __init__(self, capacity: int) -> None:
        if capacity < 1:
            raise ValueError(f"capacity must be >= 1, got {capacity}")
        self.capacity = capacity
        self._dq: deque[Any] = deque()
        self._lock = threading.Lock()
        self._ready = threading.Event()
        self.puts = 0
        self.drops = 0

    def put(self, item: Any) -> None:
        with self._lock:
            if len(self._dq) >= self.capacity:
                self._dq.popleft()
                self.drops += 1
            self._dq.append(item)
            self.puts += 1
        self._ready.set()

    def get_all(self, timeout: float) -> list[Any]:
        """Everything queued (oldest first), waiting up to `timeout` s for something."""
        self._ready.wait(timeout)
        with self._lock:
            items = list(self._dq)
            self._dq.clear()
            self._ready.clear()
        return items

    def __len__(self) -> int:
        return len(self._dq)
