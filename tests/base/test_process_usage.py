"""Process memory as the benchmarks read it."""

from __future__ import annotations

import json
import subprocess
import sys

_PROBE = """
import json
import numpy as np
from litevloc.base.process_usage import memory_mb
before = memory_mb()
block = np.ones(64 * 2**20 // 8)  # 64 MB, touched
during = memory_mb()
del block
print(json.dumps([before, during, memory_mb()]))
"""


def test_memory_grows_with_an_allocation_and_the_peak_remembers_it() -> None:
    # in a fresh interpreter: a long-lived test worker can serve the block from pages it already holds
    out = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, text=True, check=True, timeout=120)
    before, during, after = json.loads(out.stdout)
    assert during["rss"] - before["rss"] > 50 and during["peak"] >= during["rss"]
    assert after["peak"] >= during["rss"] - 1
