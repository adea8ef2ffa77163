"""Fuzz tests: hypothesis with explicit example counts and no deadline (shared 2-CPU machine).

Two profiles. `make test` runs `litevloc-fuzz`: derandomized, the same examples every run, so
the suite is reproducible. `make fuzz` runs `litevloc-fuzz-random` (`LITEVLOC_FUZZ=random`) with
a fresh seed (`--hypothesis-seed`, printed at the start and again on failure with the command
that replays it), so every run explores new inputs.

Example counts are set per test (`max_examples`); the total is printed at the end of the run."""

from __future__ import annotations

import os

import pytest
from hypothesis import HealthCheck, settings

_COMMON = {"deadline": None, "print_blob": True, "database": None,
           "suppress_health_check": [HealthCheck.too_slow, HealthCheck.function_scoped_fixture]}
settings.register_profile("litevloc-fuzz", derandomize=True, **_COMMON)
settings.register_profile("litevloc-fuzz-random", derandomize=False, **_COMMON)
RANDOM = os.environ.get("LITEVLOC_FUZZ") == "random"
settings.load_profile("litevloc-fuzz-random" if RANDOM else "litevloc-fuzz")

CASES: dict[str, int] = {}


@pytest.fixture
def count_case(request: pytest.FixtureRequest):
    name = request.node.name

    def inc() -> None:
        CASES[name] = CASES.get(name, 0) + 1

    return inc


def _seed(config: pytest.Config) -> object:
    return config.getoption("hypothesis_seed", default=None)


def pytest_report_header(config: pytest.Config) -> str:
    return f"fuzz profile: {'random, seed ' + str(_seed(config)) if RANDOM else 'derandomized'}"


def pytest_terminal_summary(terminalreporter, exitstatus, config):
    if CASES:
        terminalreporter.write_line(f"fuzz cases run: {sum(CASES.values())} " + str(dict(sorted(CASES.items()))))
    if RANDOM and exitstatus != 0:
        terminalreporter.write_line(f"fuzz seed {_seed(config)}: replay with `make fuzz SEED={_seed(config)}`")
