"""Process memory as the benchmarks read it."""

from __future__ import annotations

import numpy as np

from litevloc.base.process_usage import memory_mb


def test_memory_grows_with_an_allocation_and_the_peak_remembers_it() -> None:
    before = memory_mb()
    block = np.ones(64 * 2**20 // 8)  # 64 MB, touched
    during = memory_mb()
    del block
    after = memory_mb()
    assert during["rss"] - before["rss"] > 50 and during["peak"] >= during["rss"]
    assert after["peak"] >= during["rss"] - 1
