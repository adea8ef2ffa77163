"""Pushes: a push cut by a service restart leaves no trace and the previous version served; a
chunk whose bytes do not match the declared sha256 is refused; the held-out comparison."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import pytest

from litevloc.runtime.maps import client as mc
from litevloc.runtime.maps import keys
from litevloc.runtime.maps.errors import MapErrorKind, MapServiceError
from litevloc.runtime.maps.transfer import read_chunk, transfer_manifest
from litevloc.runtime.tools.map_candidates import HeldOutScore, not_worse
from tests.runtime.maps.conftest import Service, open_client, tiny_map
from tests.runtime.maps.test_access import seed_gate


def test_a_push_cut_by_a_restart_leaves_the_previous_version(tmp_path: Path) -> None:
    svc = Service(tmp_path / "store", gate=seed_gate)
    try:
        v1 = svc.server.publish("office", tiny_map(tmp_path / "a", seed=0))
        c = open_client(svc.endpoint)
        src = tiny_map(tmp_path / "b", seed=2)
        m = transfer_manifest(src, 4096)
        up = mc.ask_json(c, keys.push_begin_key("office"), {"kind": "map", "transfer": m.to_json()})["upload"]
        for i, ch in enumerate(m.chunks[: len(m.chunks) // 2]):
            mc.ask(c, keys.push_chunk_key("office", up, i), read_chunk(src, ch))
        # a chunk whose bytes are not what the push declared is refused
        with pytest.raises(MapServiceError) as e:
            mc.ask(c, keys.push_chunk_key("office", up, len(m.chunks) - 1), b"x" * 10)
        assert e.value.kind is MapErrorKind.CHECKSUM
        # committing an incomplete push publishes nothing
        with pytest.raises(MapServiceError) as e:
            mc.ask(c, keys.push_commit_key("office", up))
        assert e.value.kind is MapErrorKind.BAD_REQUEST and "not received" in str(e.value)
        c.close()
        c = open_client(svc.endpoint)
        up2 = mc.ask_json(c, keys.push_begin_key("office"), {"kind": "map", "transfer": m.to_json()})["upload"]
        mc.ask(c, keys.push_chunk_key("office", up2, 0), read_chunk(src, m.chunks[0]))
        c.close()
        svc.restart()  # the service goes down mid-push
        assert not list((tmp_path / "store" / ".uploads").glob("*"))
        assert svc.store.latest("office") == v1 and svc.store.versions("office") == [v1]
        c = open_client(svc.endpoint)
        with pytest.raises(MapServiceError) as e:
            mc.ask(c, keys.push_commit_key("office", up2))
        assert e.value.kind is MapErrorKind.NOT_FOUND
        res = mc.push_map(c, "office", src, chunk_bytes=4096)  # the robot pushes again
        assert res.published and res.info is not None and res.info.parent == v1.version
        c.close()
    finally:
        svc.close()


def test_push_of_something_that_is_neither_map_nor_recording(service: Service, client: Any, tmp_path: Path) -> None:
    (tmp_path / "folder").mkdir()
    with pytest.raises(MapServiceError) as e:
        mc.push_map(client, "office", tmp_path / "folder")
    assert e.value.kind is MapErrorKind.BAD_REQUEST
    with pytest.raises(MapServiceError) as e:
        mc.ask_json(client, keys.push_begin_key("office"), {"kind": "pickle", "transfer": {}})
    assert e.value.kind is MapErrorKind.BAD_REQUEST


def test_held_out_comparison() -> None:
    cur = HeldOutScore(10, 8, 0.05)
    assert not_worse(HeldOutScore(10, 8, 0.055), cur, 0.01)[0]
    ok, why = not_worse(HeldOutScore(10, 7, 0.03), cur, 0.01)
    assert not ok and "7/10" in why and "8/10" in why
    ok, why = not_worse(HeldOutScore(10, 9, 0.08), cur, 0.01)
    assert not ok and "median error 8.0 cm" in why
    assert not_worse(HeldOutScore(10, 0, math.nan), HeldOutScore(10, 0, math.nan), 0.01)[0]


@pytest.mark.timeout(60)
def test_service_killed_during_a_push_serves_the_previous_version(tmp_path: Path) -> None:
    import os
    import signal
    import subprocess
    import sys
    import threading

    from litevloc.runtime.maps.store import MapStore
    from tests.runtime.zenoh_helpers import free_port

    root, ep = tmp_path / "store", f"tcp/127.0.0.1:{free_port()}"
    v1 = MapStore(root, chunk_bytes=4096).add_version("office", tiny_map(tmp_path / "a", seed=0))
    proc = subprocess.Popen([sys.executable, "-m", "tests.runtime.maps.killable_service", str(root), ep],
                            stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None and proc.stdout.readline().strip() == "READY"
        c = open_client(ep)
        pushed: list[BaseException] = []

        def push() -> None:
            try:
                mc.push_map(c, "office", tiny_map(tmp_path / "b", seed=2), chunk_bytes=4096, commit_timeout_s=20)
            except BaseException as exc:  # the service dies before it answers
                pushed.append(exc)

        t = threading.Thread(target=push)
        t.start()
        assert proc.stdout.readline().strip() == "STAGED"  # the candidate is on disk, not yet a version
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(10)
        t.join(30)
        c.close()
        assert pushed and isinstance(pushed[0], MapServiceError)
    finally:
        if proc.poll() is None:
            proc.kill()
    svc = Service(root)  # the restarted service: the previous version, nothing half-written
    try:
        assert svc.store.latest("office") == v1 and svc.store.versions("office") == [v1]
        assert not list((root / "office" / ".staging").iterdir()) and not (root / ".uploads").exists()
        c = open_client(svc.endpoint)
        assert mc.fetch_map(c, "office", None, tmp_path / "cache").version == v1.version
        c.close()
    finally:
        svc.close()


def test_an_abandoned_push_is_forgotten(service: Service, client: Any, tmp_path: Path,
                                        monkeypatch: pytest.MonkeyPatch) -> None:
    src = tiny_map(tmp_path / "b", seed=2)
    m = transfer_manifest(src, 4096).to_json()
    first = mc.ask_json(client, keys.push_begin_key("office"), {"kind": "map", "transfer": m})["upload"]
    monkeypatch.setattr("litevloc.runtime.maps.server.UPLOAD_TTL_S", -1.0)
    mc.ask_json(client, keys.push_begin_key("office"), {"kind": "map", "transfer": m})
    assert not (tmp_path / "store" / ".uploads" / first).exists()
    with pytest.raises(MapServiceError) as e:
        mc.ask(client, keys.push_commit_key("office", first))
    assert e.value.kind is MapErrorKind.NOT_FOUND
