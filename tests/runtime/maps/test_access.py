"""Who may do what (as the odometry rule is tested in tests/runtime/test_security.py): a client
without credentials cannot read, an authenticated but unlisted one cannot read or push, a
reader cannot push, a writer can push, and nobody can overwrite or delete a version."""

from __future__ import annotations

import json
import shutil
import time
from pathlib import Path
from typing import Any

import pytest

from litevloc.config.schema import ZenohConfig
from litevloc.runtime.maps import client as mc
from litevloc.runtime.maps import keys
from litevloc.runtime.maps.access import map_acl
from litevloc.runtime.maps.errors import MapErrorKind, MapServiceError
from litevloc.runtime.maps.server import PushVerdict
from litevloc.runtime.maps.transfer import file_entries
from litevloc.runtime.transport.bus import BusError, open_session
from litevloc.runtime.transport.security import usrpwd_auth
from tests.runtime.maps.conftest import Service, tiny_map


def seed_gate(name: str, current: Path | None, upload: Path, kind: str, out: Path) -> PushVerdict:
    """Accepts a pushed map whose seed is even (standing in for the held-out check)."""
    seed = int(json.loads((upload / "manifest.json").read_text())["meta"]["seed"])
    if seed % 2:
        return PushVerdict(False, f"held-out check worse: seed {seed} is odd", {"seed": seed})
    shutil.copytree(upload, out)
    return PushVerdict(True, "held-out check not worse", {"seed": seed})


def _peer(ep: str, user: str | None, password: str | None, require: bool = True) -> Any:
    """A client of the service's router; with `require=False` a peer that starts unconnected."""
    extra = usrpwd_auth(user, password) if user else None
    return open_session(ZenohConfig(mode="client" if require else "peer", listen=(), connect=(ep,),
                                    connect_timeout_s=1.0, require_connect=require, extra=extra))


@pytest.mark.timeout(60)
def test_only_listed_robots_read_and_only_writers_push(tmp_path: Path) -> None:
    users = tmp_path / "users.txt"
    users.write_text("mapsvc:svc-pw\nrobot1:r1-pw\nviewer:v-pw\nstranger:s-pw\n")
    users.chmod(0o600)
    svc = Service(tmp_path / "store", gate=seed_gate, access_control=map_acl(["viewer"], ["robot1"]),
                  extra=usrpwd_auth("mapsvc", "svc-pw", str(users)))
    try:
        v1 = svc.server.publish("office", tiny_map(tmp_path / "a", seed=0))
        # 1. no credentials: no session at all; a wrong password: connected to nothing, reads nothing
        with pytest.raises(BusError):
            _peer(svc.endpoint, None, None)
        # 2. authenticated but unlisted: every read and push is filtered by the ACL
        stranger = _peer(svc.endpoint, "stranger", "s-pw")
        try:
            with pytest.raises(MapServiceError) as e:
                mc.fetch_map(stranger, "office", None, tmp_path / "c_stranger", timeout_s=0.5, allow_offline=False)
            assert e.value.kind is MapErrorKind.UNREACHABLE
            with pytest.raises(MapServiceError) as e:
                mc.push_map(stranger, "office", tiny_map(tmp_path / "s", seed=2), chunk_bytes=4096, timeout_s=0.5)
            assert e.value.kind is MapErrorKind.UNREACHABLE
        finally:
            stranger.close()
        # 3. a reader reads, but its push never reaches the service
        viewer = _peer(svc.endpoint, "viewer", "v-pw")
        try:
            assert mc.fetch_map(viewer, "office", None, tmp_path / "c_viewer").version == v1.version
            with pytest.raises(MapServiceError) as e:
                mc.push_map(viewer, "office", tiny_map(tmp_path / "v", seed=2), chunk_bytes=4096, timeout_s=0.5)
            assert e.value.kind is MapErrorKind.UNREACHABLE
            with pytest.raises(MapServiceError):
                mc.request_rollback(viewer, "office", v1.version, timeout_s=0.5)
        finally:
            viewer.close()
        assert svc.store.versions("office") == [v1]
        # 4. the listed robot pushes: refused with the gate's reason, or published and announced
        robot = _peer(svc.endpoint, "robot1", "r1-pw")
        try:
            bad = mc.push_map(robot, "office", tiny_map(tmp_path / "odd", seed=3), chunk_bytes=4096)
            assert not bad.published and "seed 3 is odd" in bad.reason and bad.details == {"seed": 3}
            assert svc.store.versions("office") == [v1]
            good = mc.push_map(robot, "office", tiny_map(tmp_path / "even", seed=4), chunk_bytes=4096)
            assert good.published and good.info is not None and good.info.parent == v1.version
            assert svc.store.latest("office") == good.info
            got = mc.fetch_map(robot, "office", None, tmp_path / "c_robot")
            assert got.version == good.info.version and file_entries(got.path) == file_entries(tmp_path / "even")
            # 5. nobody overwrites or deletes a version: puts and deletes on the map keys go nowhere
            before = file_entries(svc.store.map_path("office", v1.version))
            robot.put(keys.chunk_key("office", v1.version, 0), b"evil")
            robot.put(keys.latest_key("office"), keys.dumps(v1.to_json()))
            robot.delete(keys.manifest_key("office", v1.version))
            time.sleep(0.3)
            assert file_entries(svc.store.map_path("office", v1.version)) == before
            assert svc.store.latest("office") == good.info and len(svc.store.versions("office")) == 2
        finally:
            robot.close()
    finally:
        svc.close()


def test_a_wrong_password_gets_no_map(tmp_path: Path) -> None:
    users = tmp_path / "users.txt"
    users.write_text("mapsvc:svc-pw\nrobot1:r1-pw\n")
    users.chmod(0o600)
    svc = Service(tmp_path / "store", access_control=map_acl([], ["robot1"]),
                  extra=usrpwd_auth("mapsvc", "svc-pw", str(users)))
    try:
        svc.server.publish("office", tiny_map(tmp_path / "a", seed=0))
        with pytest.raises(BusError):  # a client with a wrong password gets no session ...
            _peer(svc.endpoint, "robot1", "wrong")
        bad = _peer(svc.endpoint, "robot1", "wrong", require=False)  # ... a peer that keeps trying, no map
        try:
            with pytest.raises(MapServiceError) as e:
                mc.fetch_map(bad, "office", None, tmp_path / "c", timeout_s=0.5, allow_offline=False)
            assert e.value.kind is MapErrorKind.UNREACHABLE
        finally:
            bad.close()
    finally:
        svc.close()


def test_acl_block_shape() -> None:
    acl = map_acl(["viewer"], ["robot1"], admins=["ops"], by="cert_common_name", allow_other=["robot1/**"])
    assert acl["default_permission"] == "deny"
    subj = {s["id"]: s for s in acl["subjects"]}
    assert subj["map_readers"]["cert_common_names"] == ["ops", "robot1", "viewer"]
    assert subj["map_writers"]["cert_common_names"] == ["robot1"]
    assert not any(set(r["messages"]) & {"put", "delete"} and r["flows"] == ["ingress"]
                   and any(k.startswith("litevloc/maps") for k in r["key_exprs"]) for r in acl["rules"])
    with pytest.raises(ValueError):
        map_acl([], [])


@pytest.mark.timeout(60)
def test_tls_identity_by_certificate_common_name(tmp_path: Path) -> None:
    """With mutual TLS the ACL names robots by their certificate's common name."""
    pytest.importorskip("cryptography.x509")
    from litevloc.runtime.transport.security import tls_config
    from tests.runtime.test_tls import make_pki
    from tests.runtime.zenoh_helpers import free_port

    make_pki(tmp_path, "ca", ["mapsvc", "robot1", "viewer"])
    svc = Service(tmp_path / "store", gate=seed_gate,
                  tls=tls_config(str(tmp_path / "ca.pem"), str(tmp_path / "mapsvc.pem"), str(tmp_path / "mapsvc.key")),
                  access_control=map_acl(["viewer"], ["robot1"], by="cert_common_name"),
                  endpoint=f"tls/127.0.0.1:{free_port()}")
    try:
        v1 = svc.server.publish("office", tiny_map(tmp_path / "a", seed=0))

        def robot(cn: str) -> Any:
            tls = tls_config(str(tmp_path / "ca.pem"), str(tmp_path / f"{cn}.pem"), str(tmp_path / f"{cn}.key"),
                             listen=False)
            return open_session(ZenohConfig(mode="client", listen=(), connect=(svc.endpoint,), connect_timeout_s=2.0,
                                            tls=tls))

        viewer = robot("viewer")
        try:
            assert mc.fetch_map(viewer, "office", None, tmp_path / "cv").version == v1.version
            with pytest.raises(MapServiceError) as e:
                mc.push_map(viewer, "office", tiny_map(tmp_path / "v", seed=2), chunk_bytes=4096, timeout_s=0.5)
            assert e.value.kind is MapErrorKind.UNREACHABLE
        finally:
            viewer.close()
        r1 = robot("robot1")
        try:
            assert mc.push_map(r1, "office", tiny_map(tmp_path / "e", seed=2), chunk_bytes=4096).published
        finally:
            r1.close()
    finally:
        svc.close()
