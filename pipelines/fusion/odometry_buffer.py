"""The odometry `OnlineFusion` keeps for `odom_buffer_s`: poses at capture times, paths between them."""

from __future__ import annotations

import itertools
import math
from collections import deque
from collections.abc import Iterator

import numpy as np
from numpy.typing import NDArray

from litevloc.base.geometry import interpolate_pose
from litevloc.pipelines.fusion.graph_ops import angle, inv

F64 = NDArray[np.float64]


class OdometryBuffer:
    """(t_ns, T_odom_base) in time order; older than `buffer_s` behind the newest is dropped
    (two messages always kept). `max_future_s`: how far past the newest `at()` extrapolates."""

    def __init__(self, buffer_s: float, max_future_s: float) -> None:
        self.buffer_s, self.max_future_s = buffer_s, max_future_s
        self._odom: deque[tuple[int, F64]] = deque()

    def __len__(self) -> int:
        return len(self._odom)

    def __bool__(self) -> bool:
        return bool(self._odom)

    def __iter__(self) -> Iterator[tuple[int, F64]]:
        return iter(self._odom)

    @property
    def first_t(self) -> int:
        return self._odom[0][0]

    @property
    def newest(self) -> tuple[int, F64]:
        return self._odom[-1]

    def add(self, t_ns: int, T: F64) -> None:
        self._odom.append((t_ns, T))
        horizon = t_ns - int(self.buffer_s * 1e9)
        while len(self._odom) > 2 and self._odom[1][0] < horizon:
            self._odom.popleft()

    def at(self, t_ns: int) -> F64 | None:
        """T_odom_base at t_ns interpolated from the buffer (None outside it)."""
        if not self._odom:
            return None
        t_first, t_last = self._odom[0][0], self._odom[-1][0]
        if t_ns < t_first:
            return None
        if t_ns >= t_last:
            if t_ns - t_last > self.max_future_s * 1e9:
                return None
            if t_ns == t_last or len(self._odom) < 2:
                return self._odom[-1][1]
            (tp, Tp), (tl, Tl) = self._odom[-2], self._odom[-1]
            return interpolate_pose(
                Tp, Tl, (t_ns - tp) / (tl - tp)
            )  # s > 1: constant-velocity extrapolation
        times = [t for t, _ in self._odom]  # bounded (odom_buffer_s of messages)
        i = int(np.searchsorted(times, t_ns, side="right"))
        t0, T0 = self._odom[i - 1]
        t1, T1 = self._odom[i]
        return interpolate_pose(T0, T1, (t_ns - t0) / (t1 - t0))

    def path(self, t_a: int, t_b: int) -> tuple[float, float]:
        """(metres travelled, radians turned) between two times (t_a <= t_b; the messages between
        them, no interpolation at the ends): the path, not the net motion, so driving out and back
        or a turn on the spot counts in full."""
        steps = [T for t, T in self._odom if t_a <= t <= t_b]
        dist = turn = 0.0
        for T0, T1 in itertools.pairwise(steps):
            D = inv(T0) @ T1
            dist += math.sqrt(float(D[:3, 3] @ D[:3, 3]))
            turn += angle(D[:3, :3])
        return dist, turn

    def within(self, t_a: int, t_b: int, max_m: float, max_deg: float) -> bool:
        """Whether the odometry between two times travelled less than `max_m` metres and turned
        less than `max_deg` degrees in all (`path`)."""
        dist, turn = self.path(t_a, t_b)
        return dist < max_m and turn < math.radians(max_deg)
