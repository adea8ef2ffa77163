"""Security: explicit Zenoh listening, authenticated + access-controlled odometry input,
checksummed map/model files, and no code path that unpickles or evaluates user data."""

from __future__ import annotations

import ast
import json
import time
from pathlib import Path

import numpy as np
import pytest

from litevloc.config import load_config
from litevloc.config.schema import ZenohConfig
from litevloc.hw.messages import Odometry
from litevloc.hw.odometry import OdometryReceiver, encode_odometry
from litevloc.runtime.transport.bus import Bus, BusError, LiteVLocPublisher, zenoh_config
from litevloc.runtime.transport.security import odometry_acl, usrpwd_auth
from tests.runtime.zenoh_helpers import free_port

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("preset", ["default", "7scenes", "oak-d"])
def test_presets_listen_only_where_told(preset: str) -> None:
    cfg = load_config(preset)
    c = zenoh_config(cfg.zenoh)
    listen = json.loads(c.get_json("listen/endpoints"))
    assert listen == list(cfg.zenoh.listen)
    for ep in listen:
        assert "0.0.0.0" not in ep and "[::]" not in ep, ep
    assert json.loads(c.get_json("scouting/multicast/enabled")) is False
    assert json.loads(c.get_json("connect/endpoints")) == list(cfg.zenoh.connect)
    # client mode never listens, whatever `listen` says
    cl = zenoh_config(ZenohConfig(mode="client", connect=("tcp/127.0.0.1:7447",)))
    assert json.loads(cl.get_json("listen/endpoints")) == []


def test_security_blocks_reach_zenoh_config() -> None:
    acl = odometry_acl("odom", ["robot"], namespace="r1")
    c = zenoh_config(ZenohConfig(access_control=acl, extra=usrpwd_auth("litevloc", "pw", "/etc/users.txt")))
    assert json.loads(c.get_json("access_control/default_permission")) == "deny"
    assert json.loads(c.get_json("transport/auth/usrpwd/dictionary_file")) == "/etc/users.txt"
    assert any("r1/litevloc/**" in r["key_exprs"] for r in json.loads(c.get_json("access_control/rules")))
    with pytest.raises(ValueError):
        usrpwd_auth("only-user")
    with pytest.raises(ValueError):
        odometry_acl("odom", [])


def _wait(pred, timeout: float = 3.0) -> bool:
    t_end = time.monotonic() + timeout
    while time.monotonic() < t_end:
        if pred():
            return True
        time.sleep(0.02)
    return bool(pred())


@pytest.mark.timeout(60)
def test_only_authorised_peer_can_publish_odometry(tmp_path: Path) -> None:
    users = tmp_path / "users.txt"
    users.write_text("litevloc:svc-pw\nrobot:robot-pw\nviewer:viewer-pw\n")
    users.chmod(0o600)
    ep = f"tcp/127.0.0.1:{free_port()}"
    runtime_cfg = ZenohConfig(listen=(ep,), access_control=odometry_acl("odom", ["robot"]),
                              extra=usrpwd_auth("litevloc", "svc-pw", str(users)))
    got: list[Odometry] = []
    with Bus(runtime_cfg) as bus:
        receiver = OdometryReceiver(bus.session, "odom", got.append)
        publisher = LiteVLocPublisher(bus)

        def peer(user: str | None, password: str | None, require: bool = True) -> Bus:
            extra = usrpwd_auth(user, password) if user else None
            return Bus(ZenohConfig(listen=(), connect=(ep,), connect_timeout_s=1.0, require_connect=require,
                                   extra=extra))

        def send(b: Bus, n: int, t0: int) -> None:
            pub = b.session.declare_publisher("odom")
            for i in range(n):
                pub.put(encode_odometry(Odometry(t0 + i * 5_000_000, np.eye(4))))
                time.sleep(0.01)

        # 1. no credentials: no transport at all (start fails with require_connect) ...
        with pytest.raises(BusError):
            peer(None, None)
        # ... and a peer that keeps trying with a wrong password gets nothing through
        with peer("robot", "wrong", require=False) as bad:
            assert not bad.connectivity()["connected"]
            send(bad, 10, 1_000_000_000)
        # 2. authenticated, but not allowed to publish odometry: filtered by the ACL
        with peer("viewer", "viewer-pw") as viewer:
            assert viewer.connectivity()["connected"]
            # it may read the runtime's outputs ...
            seen: list[bytes] = []
            sub = viewer.session.declare_subscriber("litevloc/status", lambda s: seen.append(s.payload.to_bytes()))
            time.sleep(0.3)
            publisher.publish_status({"state": "INIT"})
            assert _wait(lambda: len(seen) == 1)
            sub.undeclare()
            # ... but its odometry never reaches the runtime
            send(viewer, 10, 2_000_000_000)
            time.sleep(0.5)
        assert got == [] and receiver.report()["received"] == 0
        # 3. the authorised robot's odometry arrives and is decoded
        with peer("robot", "robot-pw") as robot:
            time.sleep(0.3)
            send(robot, 10, 3_000_000_000)
            assert _wait(lambda: len(got) == 10)
        assert [o.t_ns for o in got] == [3_000_000_000 + i * 5_000_000 for i in range(10)]
        receiver.close()
        publisher.close()


def test_model_file_is_checksummed_before_use(tmp_path: Path) -> None:
    """A model file that differs from the manifest's sha256 is refused (maps: tests/pipelines/topomap/test_io.py)."""
    import hashlib

    from litevloc.base.params.models import ModelsConfig
    from litevloc.models.catalog import EXPORT_VERSION, OPSET, spec_for
    from litevloc.models.registry import (
        ModelError,
        locate,
        sha256_file,
        write_manifest,
    )

    model_id = "aliked-n16-240x320-k512"
    spec = spec_for(model_id)
    # a manifest entry as `litevloc models export` writes it, for a file with other bytes than these
    entry = {"export_version": EXPORT_VERSION, "opset": OPSET, "kind": spec.kind, "arch": spec.arch,
             "input_hw": list(spec.input_hw) if spec.input_hw else None, "top_k": spec.top_k,
             "quantization": spec.quantization, "onnx_sha256": hashlib.sha256(b"the exported model").hexdigest()}
    (tmp_path / spec.filename).write_bytes(b"not the exported model")
    write_manifest(tmp_path, {"format": 1, "models": {model_id: entry}})
    cfg = ModelsConfig(cache_dir=str(tmp_path))
    with pytest.raises(ModelError, match="does not match the sha256"):
        locate(model_id, cfg)
    entry["onnx_sha256"] = sha256_file(tmp_path / spec.filename)
    write_manifest(tmp_path, {"format": 1, "models": {model_id: entry}})
    assert locate(model_id, cfg)[0] == tmp_path / spec.filename


_FORBIDDEN_CALLS = {("pickle", "load"), ("pickle", "loads"), ("yaml", "load"), ("yaml", "unsafe_load"),
                    ("marshal", "loads"), ("dill", "load"), ("joblib", "load")}


def test_no_code_path_executes_or_unpickles_user_data() -> None:
    """Static check over the shipped packages: no eval/exec, no pickle/marshal/unsafe YAML,
    numpy loads with allow_pickle=False, torch.load only with weights_only=True."""
    problems: list[str] = []
    for pkg in ("runtime", "pipelines", "hw", "sim", "models", "config", "base"):
        for f in sorted((ROOT / pkg).rglob("*.py")):
            tree = ast.parse(f.read_text(), str(f))
            for node in ast.walk(tree):
                if isinstance(node, ast.Import | ast.ImportFrom):
                    names = [a.name for a in node.names] + ([node.module] if isinstance(node, ast.ImportFrom)
                                                             and node.module else [])
                    if any(n.split(".")[0] in ("pickle", "marshal", "dill", "shelve") for n in names):
                        problems.append(f"{f}:{node.lineno}: imports {names}")
                if not isinstance(node, ast.Call):
                    continue
                fn = node.func
                kw = {k.arg: k.value for k in node.keywords}
                if isinstance(fn, ast.Name) and fn.id in ("eval", "exec", "compile", "__import__"):
                    problems.append(f"{f}:{node.lineno}: {fn.id}()")
                if isinstance(fn, ast.Attribute) and isinstance(fn.value, ast.Name):
                    mod, attr = fn.value.id, fn.attr
                    if (mod, attr) in _FORBIDDEN_CALLS:
                        problems.append(f"{f}:{node.lineno}: {mod}.{attr}()")
                    if mod in ("np", "numpy") and attr == "load":
                        ap = kw.get("allow_pickle")
                        if ap is not None and not (isinstance(ap, ast.Constant) and ap.value is False):
                            problems.append(f"{f}:{node.lineno}: np.load(allow_pickle=...) not False")
                    if mod == "torch" and attr == "load":
                        wo = kw.get("weights_only")
                        if not (isinstance(wo, ast.Constant) and wo.value is True):
                            problems.append(f"{f}:{node.lineno}: torch.load without weights_only=True")
                    if mod == "subprocess" or (mod == "os" and attr in ("system", "popen")):
                        problems.append(f"{f}:{node.lineno}: {mod}.{attr}()")
    assert not problems, "\n".join(problems)
