"""Serving and fetching on loopback: list/latest/versions, a fetch that verifies and caches, a cut
transfer resumed, a corrupted chunk refused and fetched again, the offline start from the cache,
announcements on publish and rollback."""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import Any

import pytest

from litevloc.runtime.maps import client as mc
from litevloc.runtime.maps import keys
from litevloc.runtime.maps.errors import MapErrorKind, MapServiceError
from litevloc.runtime.maps.store import MapVersionInfo
from litevloc.runtime.maps.transfer import file_entries
from tests.runtime.maps.conftest import Service, open_client, tiny_map


def test_list_latest_versions_and_fetch(service: Service, client: Any, tmp_path: Path) -> None:
    v1 = service.server.publish("office", tiny_map(tmp_path / "a", seed=1))
    v2 = service.server.publish("office", tiny_map(tmp_path / "b", seed=2))
    idx = mc.ask_json(client, keys.INDEX)
    assert idx["maps"] == [{"name": "office", "latest": v2.to_json()}]
    assert mc.latest_version(client, "office") == v2
    vs = mc.list_versions(client, "office")
    assert vs["latest"] == v2.version and vs["versions"] == [v1, v2]
    seen: list[tuple[int, int]] = []
    got = mc.fetch_map(client, "office", None, tmp_path / "cache", progress=lambda d, t: seen.append((d, t)))
    assert got.version == v2.version and not got.offline and not got.from_cache
    assert file_entries(got.path) == file_entries(tmp_path / "b")
    assert got.chunks_fetched == len(service.store.manifest("office", v2.version).chunks) > 5
    assert seen[-1] == (v2.size_bytes, v2.size_bytes)
    old = mc.fetch_map(client, "office", v1.version[:12], tmp_path / "cache")
    assert old.version == v1.version and file_entries(old.path) == file_entries(tmp_path / "a")
    # the cache's latest stays the latest the robot was given, not the older version it asked for
    assert mc.MapStore(tmp_path / "cache").latest("office") == v2
    with pytest.raises(MapServiceError) as e:
        mc.fetch_map(client, "attic", None, tmp_path / "cache")
    assert e.value.kind is MapErrorKind.NOT_FOUND


def test_a_cut_fetch_resumes_keeping_the_verified_chunks(service: Service, client: Any, tmp_path: Path) -> None:
    v = service.server.publish("office", tiny_map(tmp_path / "a", seed=1))
    n = len(service.store.manifest("office", v.version).chunks)

    class Cut(Exception):
        pass

    def cut_after_half(done: int, total: int) -> None:
        if done > total // 2:
            raise Cut

    with pytest.raises(Cut):
        mc.fetch_map(client, "office", None, tmp_path / "cache", progress=cut_after_half)
    assert not mc.MapStore(tmp_path / "cache").versions("office")  # nothing half-fetched is a version
    got = mc.fetch_map(client, "office", None, tmp_path / "cache")
    assert 0 < got.chunks_resumed < n and got.chunks_resumed + got.chunks_fetched == n
    assert file_entries(got.path) == file_entries(tmp_path / "a")


def test_a_corrupted_chunk_is_refused_and_fetched_again(service: Service, client: Any, tmp_path: Path,
                                                        monkeypatch: pytest.MonkeyPatch) -> None:
    v = service.server.publish("office", tiny_map(tmp_path / "a", seed=1))
    real = service.server._chunk
    bad = {"left": 1}

    def flaky(name: str, version: str, index: str) -> bytes:
        data = real(name, version, index)
        if index == "3" and bad["left"] > 0:
            bad["left"] -= 1
            return bytes([data[0] ^ 0xFF]) + data[1:]
        return data

    monkeypatch.setattr(service.server, "_chunk", flaky)
    got = mc.fetch_map(client, "office", None, tmp_path / "cache")
    assert got.chunks_refetched == 1 and file_entries(got.path) == file_entries(tmp_path / "a")
    # a chunk that stays corrupt: a clear error after the retries, nothing cached
    bad["left"] = 100
    with pytest.raises(MapServiceError) as e:
        mc.fetch_map(client, "office", v.version, tmp_path / "cache2", retries=2)
    assert e.value.kind is MapErrorKind.CHECKSUM and "chunk 3" in str(e.value)
    assert not mc.MapStore(tmp_path / "cache2").versions("office")


def test_a_corrupted_chunk_on_disk_is_not_resumed(service: Service, client: Any, tmp_path: Path) -> None:
    v = service.server.publish("office", tiny_map(tmp_path / "a", seed=1))
    m = service.store.manifest("office", v.version)
    partial = tmp_path / "cache" / ".partial" / "office" / v.version
    for c in m.chunks:  # a previous transfer wrote every chunk, one of them damaged since
        data = mc.read_chunk(service.store.map_path("office", v.version), c)
        mc.write_chunk(partial, c, data)
    c0 = m.chunks[0]
    mc.write_chunk(partial, c0, b"\x00" * c0.size)
    got = mc.fetch_map(client, "office", None, tmp_path / "cache")
    assert got.chunks_fetched == 1 and got.chunks_resumed == len(m.chunks) - 1
    assert file_entries(got.path) == file_entries(tmp_path / "a")


def test_robot_starts_from_the_cache_when_the_service_is_down(tmp_path: Path) -> None:
    svc = Service(tmp_path / "store")
    v = svc.server.publish("office", tiny_map(tmp_path / "a", seed=1))
    c = open_client(svc.endpoint)
    assert mc.fetch_map(c, "office", None, tmp_path / "cache").version == v.version
    c.close()
    svc.close()
    from litevloc.config.schema import ZenohConfig
    from litevloc.runtime.transport.bus import open_session

    lone = open_session(ZenohConfig(listen=(), connect=(svc.endpoint,), require_connect=False))
    try:
        got = mc.fetch_map(lone, "office", None, tmp_path / "cache", timeout_s=0.5)
        assert got.offline and got.version == v.version and file_entries(got.path) == file_entries(tmp_path / "a")
        with pytest.raises(MapServiceError) as e:
            mc.fetch_map(lone, "office", None, tmp_path / "cache", timeout_s=0.5, allow_offline=False)
        assert e.value.kind is MapErrorKind.UNREACHABLE
        with pytest.raises(MapServiceError) as e:  # nothing cached under this name: no offline start
            mc.fetch_map(lone, "attic", None, tmp_path / "cache", timeout_s=0.5)
        assert e.value.kind is MapErrorKind.UNREACHABLE
    finally:
        lone.close()


def test_announcements_on_publish_and_rollback(service: Service, client: Any, tmp_path: Path) -> None:
    got: list[MapVersionInfo] = []
    ev = threading.Event()

    def on(info: MapVersionInfo) -> None:
        got.append(info)
        ev.set()

    sub = mc.subscribe_announcements(client, "office", on)
    time.sleep(0.3)
    v1 = service.server.publish("office", tiny_map(tmp_path / "a", seed=1))
    v2 = service.server.publish("office", tiny_map(tmp_path / "b", seed=2))
    back = mc.request_rollback(client, "office", v1.version[:8])
    assert back == v1 and service.store.latest("office") == v1
    t_end = time.monotonic() + 3
    while len(got) < 3 and time.monotonic() < t_end:
        time.sleep(0.02)
    assert got == [v1, v2, v1]
    # a malformed announcement is counted and skipped, the callback never sees it
    client.put(keys.announce_key("office"), b"{not json")
    client.put(keys.announce_key("office"), keys.dumps({**v2.to_json(), "name": "attic"}))
    t_end = time.monotonic() + 3
    while sub.rejected < 2 and time.monotonic() < t_end:
        time.sleep(0.02)
    assert sub.rejected == 2 and len(got) == 3
    sub.close()


def test_robots_sharing_a_cache_fetch_concurrently(service: Service, tmp_path: Path) -> None:
    v = service.server.publish("office", tiny_map(tmp_path / "a", seed=1))
    clients = [open_client(service.endpoint) for _ in range(3)]
    got: list[mc.FetchedMap] = []
    errors: list[BaseException] = []

    def one(c: Any) -> None:
        try:
            got.append(mc.fetch_map(c, "office", None, tmp_path / "shared"))
        except BaseException as exc:
            errors.append(exc)

    threads = [threading.Thread(target=one, args=(c,)) for c in clients]
    for t in threads:
        t.start()
    for t in threads:
        t.join(30)
    for c in clients:
        c.close()
    assert errors == [] and [g.version for g in got] == [v.version] * 3
    assert sum(g.chunks_fetched for g in got) == len(service.store.manifest("office", v.version).chunks)


def test_one_service_per_store(service: Service) -> None:
    from litevloc.runtime.maps.server import MapServer

    with pytest.raises(MapServiceError) as e:
        MapServer(service.session, service.store)
    assert e.value.kind is MapErrorKind.CONFLICT
