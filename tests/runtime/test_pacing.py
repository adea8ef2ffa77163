from __future__ import annotations

import numpy as np

from litevloc.hw.messages import Odometry
from litevloc.runtime.service.pacing import paced


class FakeClock:
    def __init__(self) -> None:
        self.now = 100.0
        self.sleeps: list[float] = []

    def __call__(self) -> float:
        return self.now

    def sleep(self, s: float) -> None:
        self.sleeps.append(s)
        self.now += s


def msgs() -> list[Odometry]:
    return [Odometry(t, np.eye(4)) for t in (0, 500_000_000, 1_000_000_000)]


def test_real_time_and_factor() -> None:
    c = FakeClock()
    out = list(paced(msgs(), 1.0, clock=c, sleep=c.sleep))
    assert len(out) == 3 and np.allclose(c.sleeps, [0.5, 0.5]) and np.isclose(c.now, 101.0)
    c2 = FakeClock()
    list(paced(msgs(), 2.0, clock=c2, sleep=c2.sleep))
    assert np.isclose(c2.now, 100.5)


def test_as_fast_as_possible() -> None:
    c = FakeClock()
    assert len(list(paced(msgs(), 0.0, clock=c, sleep=c.sleep))) == 3 and c.sleeps == []
