"""Fuzz tests: hypothesis with explicit example counts and no deadline (shared 2-CPU machine).

Example counts are set per test (`max_examples`); the total is printed at the end of the run."""

from __future__ import annotations

import pytest
from hypothesis import HealthCheck, settings

settings.register_profile("litevloc-fuzz", deadline=None, derandomize=True, print_blob=True, database=None,
                          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
settings.load_profile("litevloc-fuzz")

CASES: dict[str, int] = {}


@pytest.fixture
def count_case(request: pytest.FixtureRequest):
    name = request.node.name

    def inc() -> None:
        CASES[name] = CASES.get(name, 0) + 1

    return inc


def pytest_terminal_summary(terminalreporter, exitstatus, config):
    if CASES:
        terminalreporter.write_line(f"fuzz cases run: {sum(CASES.values())} " + str(dict(sorted(CASES.items()))))
