"""Summaries of samples (latencies, errors, counts) for status reports and benchmarks."""

from __future__ import annotations

from collections.abc import Collection

import numpy as np
from numpy.typing import NDArray


def percentile(samples: Collection[float] | NDArray[np.floating], q: float) -> float | None:
    """The `q`-th percentile (0-100, numpy's linear interpolation) of `samples`; None when empty."""
    a = np.asarray(samples, dtype=np.float64)
    return float(np.percentile(a, q)) if a.size else None


def percentiles_ms(samples: Collection[float] | NDArray[np.floating]) -> dict[str, float]:
    """{count, median_ms, p90_ms, p99_ms, max_ms, mean_ms} of samples in milliseconds (NaN when empty)."""
    a = np.asarray(samples, dtype=np.float64)
    if a.size == 0:
        nan = float("nan")
        return {"count": 0, "median_ms": nan, "p90_ms": nan, "p99_ms": nan, "max_ms": nan, "mean_ms": nan}
    return {
        "count": int(a.size),
        "median_ms": float(np.median(a)),
        "p90_ms": float(np.percentile(a, 90)),
        "p99_ms": float(np.percentile(a, 99)),
        "max_ms": float(a.max()),
        "mean_ms": float(a.mean()),
    }
