"""`litevloc run`'s source: what the service is given to read."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from litevloc.config import load_config


def test_oak_in_the_service_skips_the_jpeg_round_trip(monkeypatch: pytest.MonkeyPatch) -> None:
    """The OAK-D preset JPEG-encodes colour so that recordings replay the live pixels; the
    service records nothing, so `run` opens the camera with jpeg_quality 0 (the rest as configured)."""
    import litevloc.hw.oak as oak
    from litevloc.cli.run import open_configured_source

    got: dict[str, Any] = {}

    class FakeOak:
        def __init__(self, cfg: Any, strict: bool = False) -> None:
            got["cfg"], got["strict"] = cfg, strict

    monkeypatch.setattr(oak, "OakSource", FakeOak)
    cfg = load_config("oak-d")
    assert cfg.camera.jpeg_quality > 0
    open_configured_source(cfg, None)
    assert got["cfg"].jpeg_quality == 0 and got["cfg"].fps == cfg.camera.fps and got["strict"] == cfg.source.strict


def test_service_reads_a_lenient_recording_undecoded(tmp_path: Path) -> None:
    from litevloc.hw.messages import EncodedRgbdFrame, RgbdFrame
    from litevloc.hw.streams.mcap_io import McapSource
    from litevloc.runtime.sources import service_messages
    from tests.hw.streams.test_mcap import synthetic_messages, write

    write(tmp_path / "r.mcap", synthetic_messages(2))
    lenient = list(service_messages(McapSource(tmp_path / "r.mcap", strict=False)))
    assert sum(isinstance(m, EncodedRgbdFrame) for m in lenient) == 2
    strict = list(service_messages(McapSource(tmp_path / "r.mcap", strict=True)))  # checked as read
    assert sum(isinstance(m, RgbdFrame) for m in strict) == 2
