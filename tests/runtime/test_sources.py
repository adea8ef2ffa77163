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


def test_a_registered_driver_opens_through_both_dispatchers(monkeypatch: pytest.MonkeyPatch) -> None:
    """A new camera driver is one `SOURCE_KINDS` entry: `litevloc run` and `litevloc record` both
    open it from the config, each saying what for; an unknown kind names the known ones."""
    import dataclasses

    from litevloc.cli.run import open_configured_source
    from litevloc.config import load_config
    from litevloc.runtime.sources import SOURCE_KINDS, SourceKind, SourceUse
    from litevloc.runtime.tools.recording import open_camera_source

    opened: list[tuple[SourceUse, slice]] = []

    class FakeCamera:
        name = "fake-camera"

        def __iter__(self):  # type: ignore[no-untyped-def]
            return iter(())

    def open_fake(cfg, frames, use):  # type: ignore[no-untyped-def]
        opened.append((use, frames))
        return FakeCamera()

    monkeypatch.setitem(SOURCE_KINDS, "fake-cam", SourceKind(open_fake))
    base = load_config("default")
    cfg = dataclasses.replace(base, source=dataclasses.replace(base.source, kind="fake-cam"))
    assert isinstance(open_configured_source(cfg, None), FakeCamera)
    assert isinstance(open_camera_source(cfg, None, slice(0, 5)), FakeCamera)
    assert opened == [(SourceUse.SERVICE, slice(None)), (SourceUse.RECORD, slice(0, 5))]
    bad = dataclasses.replace(base, source=dataclasses.replace(base.source, kind="nope"))
    for dispatch in (lambda: open_configured_source(bad, None), lambda: open_camera_source(bad, None, slice(None))):
        with pytest.raises(StreamError, match=r"unknown source.kind 'nope'; known kinds: dataset, fake-cam, oak-d"):
            dispatch()
