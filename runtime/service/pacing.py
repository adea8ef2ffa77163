"""Play a message stream with its recorded timing at a real-time factor."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Iterator
from typing import Protocol, TypeVar


class Stamped(Protocol):
    @property
    def t_ns(self) -> int: ...


M = TypeVar("M", bound=Stamped)


def paced(
    messages: Iterable[M],
    rate: float,
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], object] = time.sleep,
) -> Iterator[M]:
    """Yield messages no earlier than their recorded time offset divided by `rate`.

    rate = 1 plays in real time, 2 twice as fast, 0 as fast as possible. The schedule
    is anchored at the first message, so a slow consumer makes playback late (it never
    drops messages); lateness is not compensated by skipping.
    """
    if rate < 0:
        raise ValueError(f"rate must be >= 0, got {rate}")
    t0_msg: int | None = None
    t0_wall = 0.0
    for msg in messages:
        if rate > 0:
            if t0_msg is None:
                t0_msg, t0_wall = msg.t_ns, clock()
            due = t0_wall + (msg.t_ns - t0_msg) * 1e-9 / rate
            wait = due - clock()
            if wait > 0:
                sleep(wait)
        yield msg
