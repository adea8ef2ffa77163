"""A robot following its map: an announced new version is fetched into the cache and handed to the
service's switch; the version in use is not fetched again; a version that cannot be fetched is
counted and the map in use kept."""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import Any

from litevloc.base.params.fleet import FleetParams
from litevloc.runtime.maps import client as mc
from litevloc.runtime.maps.errors import MapErrorKind, MapServiceError
from litevloc.runtime.maps.follow import MapFollower
from litevloc.runtime.maps.transfer import file_entries
from tests.runtime.maps.conftest import Service, tiny_map


def _wait(cond: Any, timeout_s: float = 5.0) -> bool:
    t_end = time.monotonic() + timeout_s
    while not cond() and time.monotonic() < t_end:
        time.sleep(0.02)
    return bool(cond())


def test_an_announced_version_is_fetched_and_handed_to_the_switch(service: Service, client: Any,
                                                                  tmp_path: Path) -> None:
    v1 = service.server.publish("office", tiny_map(tmp_path / "a", seed=1))
    params = FleetParams(cache_dir=str(tmp_path / "cache"))
    first = mc.fetch_map(client, "office", None, params.cache_dir)
    handed: list[tuple[Path, str, str]] = []
    ev = threading.Event()

    def switch(path: Path, name: str, version: str) -> None:
        handed.append((path, name, version))
        ev.set()

    follower = MapFollower(client, "office", first.version, params, switch)
    time.sleep(0.3)
    service.server.announce(v1)  # the version in use: nothing to do
    v2 = service.server.publish("office", tiny_map(tmp_path / "b", seed=2))
    assert ev.wait(5.0)
    path, name, version = handed[0]
    assert (name, version) == ("office", v2.version)
    assert file_entries(path) == file_entries(tmp_path / "b")
    assert _wait(lambda: follower.report().announced == 2)
    rep = follower.report()
    assert rep.fetched == 1 and rep.failed == 0 and rep.current == v2.version and len(handed) == 1
    follower.close()


def test_a_version_that_cannot_be_fetched_keeps_the_map_in_use(service: Service, client: Any,
                                                               tmp_path: Path) -> None:
    v1 = service.server.publish("office", tiny_map(tmp_path / "a", seed=1))
    params = FleetParams(cache_dir=str(tmp_path / "cache"))
    handed: list[str] = []

    def broken_fetch(*a: Any, **kw: Any) -> mc.FetchedMap:
        raise MapServiceError(MapErrorKind.CHECKSUM, "chunk 3 fails its sha256 after 3 retries")

    follower = MapFollower(client, "office", v1.version, params, lambda p, n, v: handed.append(v),
                           fetch=broken_fetch)
    time.sleep(0.3)
    service.server.publish("office", tiny_map(tmp_path / "b", seed=2))
    assert _wait(lambda: follower.report().failed == 1)
    rep = follower.report()
    assert handed == [] and rep.current == v1.version and rep.last_error.startswith("checksum")
    follower.close()
