"""The map-service commands: exit codes (0 done, 1 push refused, 2 user error) and what each
writes; `run --map zenoh:NAME` resolves to the fetched folder before the service starts."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from litevloc.base.params.fleet import FleetParams
from litevloc.cli.main import main
from litevloc.config.schema import ZenohConfig
from litevloc.runtime.maps.app import parse_map_uri, resolve_map
from litevloc.runtime.maps.errors import MapErrorKind, MapServiceError
from litevloc.runtime.maps.transfer import file_entries
from tests.runtime.maps.conftest import Service, tiny_map
from tests.runtime.zenoh_helpers import free_port


@pytest.fixture(autouse=True)
def _cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("LITEVLOC_MAP_CACHE", str(tmp_path / "robot-cache"))


def test_fetch_versions_rollback_push_exit_codes(service: Service, tmp_path: Path) -> None:
    v1 = service.server.publish("office", tiny_map(tmp_path / "a", seed=1))
    v2 = service.server.publish("office", tiny_map(tmp_path / "b", seed=2))
    ep = ["--connect", service.endpoint]
    out = tmp_path / "fetched"
    assert main(["map", "fetch", "office", "-o", str(out), *ep]) == 0
    assert file_entries(out) == file_entries(tmp_path / "b")
    assert main(["map", "fetch", "office", "-o", str(out), *ep]) == 2          # exists, no --force
    assert main(["map", "fetch", f"office@{v1.version[:8]}", "-o", str(out), "--force", *ep]) == 0
    assert file_entries(out) == file_entries(tmp_path / "a")
    assert main(["map", "fetch", "bad/name", "-o", str(tmp_path / "x"), *ep]) == 2
    assert main(["map", "fetch", "attic", "-o", str(tmp_path / "x"), *ep]) == 2  # no such map
    assert main(["map", "versions", "office", *ep]) == 0
    assert main(["map", "versions", "attic", *ep]) == 2
    assert main(["map", "rollback", "office", v1.version[:10], *ep]) == 0
    assert service.store.latest("office") == v1
    assert main(["map", "rollback", "office", "zz", *ep]) == 2
    assert main(["map", "rollback", "office", v2.version, "--store", str(tmp_path / "nowhere")]) == 2
    assert main(["map", "push", str(tmp_path / "missing.mcap"), "--to", "office", *ep]) == 2
    # this service has no held-out check: a push is refused (exit 1) and says why
    assert main(["map", "push", str(tiny_map(tmp_path / "c", seed=3)), "--to", "office", *ep]) == 1
    assert len(service.store.versions("office")) == 2


def test_serve_user_errors_exit_2(tmp_path: Path) -> None:
    assert main(["map", "serve", str(tmp_path / "s"), "--add", "office"]) == 2
    assert main(["map", "serve", str(tmp_path / "s"), "--mode", "client"]) == 2
    (tmp_path / "acl.yaml").write_text("readers: [a]\nwho: [b]\n")
    assert main(["map", "serve", str(tmp_path / "s"), "--acl", str(tmp_path / "acl.yaml")]) == 2


@pytest.mark.timeout(60)
def test_serve_process_serves_and_stops_on_sigterm(tmp_path: Path) -> None:
    ep = f"tcp/127.0.0.1:{free_port()}"
    proc = subprocess.Popen([sys.executable, "-m", "litevloc.cli.main", "map", "serve", str(tmp_path / "store"),
                             "--add", f"office={tiny_map(tmp_path / 'a', seed=1)}", "--listen", ep],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        assert "serving" in proc.stdout.readline()
        assert main(["map", "fetch", "office", "-o", str(tmp_path / "out"), "--connect", ep]) == 0
        assert file_entries(tmp_path / "out") == file_entries(tmp_path / "a")
    finally:
        os.kill(proc.pid, signal.SIGTERM)
        assert proc.wait(20) == 0


def test_run_map_uri_resolves_to_the_fetched_folder(service: Service, tmp_path: Path,
                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    assert parse_map_uri("zenoh:office@abc12345") == ("office", "abc12345")
    assert parse_map_uri("maps/office") is None
    v = service.server.publish("office", tiny_map(tmp_path / "a", seed=1))
    z = ZenohConfig(mode="client", listen=(), connect=(service.endpoint,))
    params = FleetParams(cache_dir=str(tmp_path / "c"), query_timeout_s=0.5)
    got = resolve_map("zenoh:office", z, params)
    assert got is not None and got.version == v.version and not got.offline
    # a robot whose router is down starts from its cache (a client cannot even open a session then)
    down = ZenohConfig(mode="client", listen=(), connect=(f"tcp/127.0.0.1:{free_port()}",), connect_timeout_s=0.3)
    off = resolve_map("zenoh:office", down, params)
    assert off is not None and off.offline and off.version == v.version
    with pytest.raises(MapServiceError) as e:
        resolve_map("zenoh:attic", down, params)
    assert e.value.kind is MapErrorKind.UNREACHABLE
    seen: dict[str, Any] = {}

    class Started(Exception):
        pass

    def fake_build_app(cfg: Any, map_path: Path, *a: Any, **k: Any) -> Any:
        seen["map"] = map_path
        raise Started

    monkeypatch.setattr("litevloc.cli.run.open_configured_source", lambda *a, **k: object())
    monkeypatch.setattr("litevloc.runtime.service.app.build_app", fake_build_app)
    monkeypatch.setattr("litevloc.runtime.sources.service_messages", lambda *a, **k: iter(()))
    with pytest.raises(Started):
        main(["run", "--config", "default", "--map", "zenoh:office", "--connect", service.endpoint])
    assert file_entries(seen["map"]) == file_entries(tmp_path / "a")
