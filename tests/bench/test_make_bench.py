"""`make bench` runs every benchmark script (issue #19: benchmarks are run, not forgotten)."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_make_bench_runs_every_benchmark() -> None:
    make = (ROOT / "Makefile").read_text()
    recipe = make.split("\nbench:", 1)[1].split("\n\n", 1)[0]
    run = set(re.findall(r"bench/(\w+\.py)", recipe))
    scripts = {p.name for p in (ROOT / "bench").glob("*.py") if not p.name.startswith("__")}
    missing = scripts - run  # (bench/_common.py runs as `bench/_common.py office-inputs`)
    assert not missing, f"bench scripts not run by `make bench`: {sorted(missing)}"
