from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pytest

from litevloc.base.geometry import gtsam_to_ros_covariance, make_T, so3_exp
from litevloc.config.schema import ZenohConfig
from litevloc.runtime.service.core import flag_covariance
from litevloc.runtime.transport.bus import (
    Bus,
    BusError,
    LiteVLocPublisher,
    topic_key,
    zenoh_config,
)
from tests.runtime.zenoh_helpers import finish_probe, free_port, start_probe


def test_config_is_explicit_loopback_no_multicast() -> None:
    c = zenoh_config(ZenohConfig())
    assert json.loads(c.get_json("listen/endpoints")) == ["tcp/127.0.0.1:7447"]
    assert json.loads(c.get_json("scouting/multicast/enabled")) is False
    assert json.loads(c.get_json("mode")) == "peer"
    c2 = zenoh_config(ZenohConfig(extra={"transport/shared_memory/enabled": False}, access_control={"enabled": False}))
    assert json.loads(c2.get_json("transport/shared_memory/enabled")) is False
    assert json.loads(c2.get_json("access_control/enabled")) is False
    c3 = zenoh_config(ZenohConfig(tls={"root_ca_certificate": "/etc/zenoh/ca.pem", "enable_mtls": True},
                                  access_control='{enabled: true, default_permission: "deny"}'))
    assert json.loads(c3.get_json("transport/link/tls/root_ca_certificate")) == "/etc/zenoh/ca.pem"
    assert json.loads(c3.get_json("access_control/default_permission")) == "deny"
    with pytest.raises(BusError, match="invalid Zenoh configuration"):
        zenoh_config(ZenohConfig(extra={"no/such/key": 1}))


def test_config_validation() -> None:
    with pytest.raises(ValueError, match="must look like"):
        ZenohConfig(listen=("127.0.0.1:7447",))
    with pytest.raises(ValueError, match="client"):
        ZenohConfig(mode="client")
    with pytest.raises(ValueError, match="namespace"):
        ZenohConfig(namespace="/robot")
    assert topic_key("robot1", "pose") == "robot1/litevloc/pose" and topic_key("", "status") == "litevloc/status"


@pytest.mark.timeout(20)
def test_unreachable_connect_fails_fast_with_clear_error() -> None:
    port = free_port()  # nothing listens there
    cfg = ZenohConfig(listen=(), connect=(f"tcp/127.0.0.1:{port}",), connect_timeout_s=0.5)
    t0 = time.monotonic()
    with pytest.raises(BusError, match=rf"cannot reach Zenoh endpoint.*127\.0\.0\.1:{port}"):
        Bus(cfg)
    assert time.monotonic() - t0 < 5.0
    client = ZenohConfig(mode="client", connect=(f"tcp/127.0.0.1:{port}",), connect_timeout_s=0.5)
    with pytest.raises(BusError, match="cannot reach"):
        Bus(client)


@pytest.mark.timeout(20)
def test_unreachable_connect_reported_in_status_when_not_required() -> None:
    port = free_port()
    cfg = ZenohConfig(listen=(), connect=(f"tcp/127.0.0.1:{port}",), connect_timeout_s=0.5, require_connect=False)
    with Bus(cfg) as bus:
        c = bus.connectivity()
        assert not c["connected"] and "no Zenoh peer" in c["problem"]


@pytest.mark.timeout(20)
def test_listen_port_in_use_is_an_error() -> None:
    port = free_port()
    with Bus(ZenohConfig(listen=(f"tcp/127.0.0.1:{port}",))), pytest.raises(BusError, match="Address already in use"):
        Bus(ZenohConfig(listen=(f"tcp/127.0.0.1:{port}",)))


def test_lost_flag_and_covariance_order() -> None:
    cov = np.diag([1.0, 2, 3, 4, 5, 6])
    assert np.allclose(np.diag(gtsam_to_ros_covariance(cov)), [4, 5, 6, 1, 2, 3])
    f = flag_covariance(np.diag([1.0, 2e5, 3, 4, 5, np.nan]), 1e4)
    assert np.allclose(np.diag(f), [1e4, 2e5, 1e4, 1e4, 1e4, 1e4])


@pytest.mark.timeout(60)
def test_cross_process_cdr_poses_at_200hz(tmp_path: Path) -> None:
    """Publisher here, subscriber in another process; CDR decoded there with rosbags."""
    port = free_port()
    ep = f"tcp/127.0.0.1:{port}"
    n = 200
    with Bus(ZenohConfig(listen=(ep,), namespace="robot1")) as bus:
        pub = LiteVLocPublisher(bus)
        out = tmp_path / "probe.json"
        proc = start_probe(ep, out, "pose,status,map_to_odom", {"pose": n, "status": 1, "map_to_odom": 1},
                           namespace="robot1")
        time.sleep(0.3)  # subscriber declarations propagate
        rng = np.random.default_rng(0)
        sent = []
        t_next = time.monotonic()
        for i in range(n):
            T = make_T(so3_exp(rng.normal(size=3) * 0.3), rng.normal(size=3))
            t_ns = 1_000_000_000 + i * 5_000_000
            pub.publish_pose(t_ns, T, np.eye(6) * 0.01)
            sent.append((t_ns, T))
            t_next += 0.005
            time.sleep(max(0.0, t_next - time.monotonic()))
        pub.publish_map_to_odom(5, np.eye(4))
        pub.publish_status({"state": "TRACKING", "x": float("nan")})
        res = finish_probe(proc, out)
    pose = res["topics"]["pose"]
    assert res["completed"] and pose["count"] == n and pose["decode_errors"] == 0
    got = {int(r[0]): np.array(r[1:]) for r in pose["data"]}
    for t_ns, T in sent:
        assert np.allclose(got[t_ns][:3], T[:3, 3], atol=1e-12)
    assert res["topics"]["status"]["data"][0] == {"state": "TRACKING", "x": None}
    lat = pose["latency"]
    assert lat["count"] == n and 0 < lat["median_ms"] < 50  # loose: a shared 2-CPU machine


def test_probe_idle_counts_from_the_first_message(tmp_path: Path) -> None:
    """A publisher slow to start (model loading under load) is waited for until the timeout; the
    idle limit only ends the probe once a stream has begun and stopped."""
    ep = f"tcp/127.0.0.1:{free_port()}"
    out = tmp_path / "probe.json"
    proc = start_probe(ep, out, "pose", {}, timeout=4.0, idle=0.5, listen=True)
    time.sleep(1.5)  # longer than idle: a probe counting from READY would be gone
    with Bus(ZenohConfig(connect=(ep,))) as bus:
        pub = LiteVLocPublisher(bus)
        time.sleep(0.3)  # subscriber declarations propagate
        for i in range(5):
            pub.publish_pose(1_000_000_000 + i, np.eye(4), np.eye(6) * 0.01)
        res = finish_probe(proc, out)
    assert res["topics"]["pose"]["count"] == 5
    assert res["ended"] == "idle"  # after the stream, not by the timeout
