from __future__ import annotations

import itertools

import pytest

from litevloc.hw.messages import Odometry, RgbdFrame, StreamError
from litevloc.runtime.sources import open_source


def test_simulator_uri_opens_a_stream() -> None:
    src = open_source("sim:office?pass=query&seed=1&duration=0.5")
    msgs = list(src)
    assert sum(isinstance(m, RgbdFrame) for m in msgs) >= 7 and any(isinstance(m, Odometry) for m in msgs)
    assert all(a.t_ns <= b.t_ns for a, b in itertools.pairwise(msgs))


def test_bad_inputs_are_named() -> None:
    with pytest.raises(StreamError):
        open_source("sim:office?pass=nonsense")
    with pytest.raises(StreamError, match="not found"):
        open_source("/nonexistent/recording.mcap")
