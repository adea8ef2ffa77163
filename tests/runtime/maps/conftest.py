"""Fixtures of the map-service tests: tiny map folders, a store, a router-mode service on a free
loopback port and client sessions to it."""

from __future__ import annotations

import hashlib
import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from litevloc.config.schema import ZenohConfig
from litevloc.runtime.maps.server import MapServer, PushGate
from litevloc.runtime.maps.store import MapStore
from litevloc.runtime.transport.bus import open_session
from tests.runtime.zenoh_helpers import free_port

CHUNK = 4096


def tiny_map(folder: Path, seed: int = 0, n_bytes: int = 40_000) -> Path:
    """A folder that passes `read_manifest` and lists its files with sha256 (not a loadable map:
    the service moves and checks files, it does not read their arrays). ~`n_bytes` of data."""
    rng = np.random.default_rng(seed)
    files = {"nodes/blob.bin": rng.integers(0, 256, n_bytes, dtype=np.uint8).tobytes(),
             "images/000000.jpg": b"\xff\xd8" + rng.integers(0, 256, 3000, dtype=np.uint8).tobytes() + b"\xff\xd9",
             "grid/empty.npy": b""}
    for rel, data in files.items():
        (folder / rel).parent.mkdir(parents=True, exist_ok=True)
        (folder / rel).write_bytes(data)
    man = {"format": "litevloc-map", "version": 3, "nodes": 1, "meta": {"seed": str(seed)},
           "files": {rel: {"sha256": hashlib.sha256(d).hexdigest(), "bytes": len(d)} for rel, d in files.items()}}
    (folder / "manifest.json").write_text(json.dumps(man, sort_keys=True))
    return folder


def open_router(ep: str, **kw: Any) -> Any:
    return open_session(ZenohConfig(listen=(ep,), **kw), mode="router")


def open_client(ep: str, **kw: Any) -> Any:
    return open_session(ZenohConfig(mode="client", listen=(), connect=(ep,), connect_timeout_s=2.0, **kw))


class Service:
    """A running map service: `store`, `server`, its `endpoint`; `restart()` reopens it."""

    def __init__(self, root: Path, gate: PushGate | None = None, endpoint: str | None = None,
                 **zenoh_kw: Any) -> None:
        self.root, self.gate, self.zenoh_kw = root, gate, zenoh_kw
        self.endpoint = endpoint or f"tcp/127.0.0.1:{free_port()}"
        self._open()

    def _open(self) -> None:
        self.store = MapStore(self.root, chunk_bytes=CHUNK)
        self.session = open_router(self.endpoint, **self.zenoh_kw)
        self.server = MapServer(self.session, self.store, self.gate)

    def close(self) -> None:
        self.server.close()
        self.session.close()

    def restart(self) -> None:
        self.close()
        self._open()


@pytest.fixture
def service(tmp_path: Path) -> Iterator[Service]:
    s = Service(tmp_path / "store")
    yield s
    s.close()


@pytest.fixture
def client(service: Service) -> Iterator[Any]:
    c = open_client(service.endpoint)
    yield c
    c.close()
