"""Small, thread-tolerant metrics for the runtime: sliding latency windows and percentiles.

`LatencyWindow` keeps the last N samples (milliseconds) in a `collections.deque` with a
`maxlen`; `add` is one atomic `deque.append` (no lock), written by one thread (the stage
or queue consumer that owns it) and read by the status thread, which copies it first.
Percentiles are computed on that copy, so a reader never blocks a writer.
"""

from __future__ import annotations

import time
from collections import deque
from typing import Any

import numpy as np

from litevloc.base.stats import percentiles_ms


def now_ns() -> int:
    """The runtime's wall-independent clock: `time.monotonic_ns()` (CLOCK_MONOTONIC on
    Linux, shared by every process on the machine, so it can time cross-process hops)."""
    return time.monotonic_ns()


class LatencyWindow:
    """The last `size` latencies in ms plus a total count; `summary()` gives median/p99."""

    def __init__(self, size: int = 1024) -> None:
        if size < 1:
            raise ValueError(f"window size must be >= 1, got {size}")
        self._samples: deque[float] = deque(maxlen=size)
        self.total = 0

    def add(self, ms: float) -> None:
        self._samples.append(ms)
        self.total += 1  # single writer

    def add_since(self, t0_ns: int) -> float:
        """Add the time elapsed since `t0_ns` (`now_ns()` clock); returns it in ms."""
        ms = (now_ns() - t0_ns) * 1e-6
        self.add(ms)
        return ms

    def snapshot(self) -> list[float]:
        # list(deque) can raise if the deque is mutated during iteration; retry briefly.
        for _ in range(8):
            try:
                return list(self._samples)
            except RuntimeError:
                continue
        return []

    def summary(self) -> dict[str, Any]:
        snap = self.snapshot()
        s = percentiles_ms(snap)
        s["last_ms"] = snap[-1] if snap else float("nan")  # `litevloc/diagnostics` reports it
        s["total"] = self.total
        return s


def jsonable(obj: Any) -> Any:
    """Replace NaN/inf floats by None (JSON has no NaN) recursively; numpy scalars -> Python."""
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [jsonable(v) for v in obj]
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, float) and not np.isfinite(obj):
        return None
    return obj
