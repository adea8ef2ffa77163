from __future__ import annotations

from pathlib import Path

import pytest

from litevloc.base.loader import ConfigError
from litevloc.config import load_config


@pytest.mark.parametrize("preset", ["default", "7scenes"])
def test_presets_have_explicit_loopback_zenoh(preset: str) -> None:
    cfg = load_config(preset)
    assert cfg.zenoh.listen == ("tcp/127.0.0.1:7447",) and not cfg.zenoh.multicast_scouting
    assert cfg.runtime.mode == "realtime" and cfg.runtime.odometry_input == "source"


def test_sections_from_yaml_and_errors(tmp_path: Path) -> None:
    p = tmp_path / "robot.yaml"
    p.write_text(
        "zenoh:\n  mode: client\n  connect: [tcp/192.168.1.10:7447]\n  namespace: robot1\n"
        "  tls: {root_ca_certificate: /etc/zenoh/ca.pem}\n"
        "runtime:\n  odometry_input: zenoh\n  odometry_key: robot1/odom\n"
        "  odometry_checks: {max_gap_s: 0.05, child_frame_id: imu_link}\n"
    )
    cfg = load_config(p)
    assert cfg.zenoh.mode == "client" and cfg.zenoh.tls == {"root_ca_certificate": "/etc/zenoh/ca.pem"}
    assert cfg.runtime.odometry_checks.max_gap_s == 0.05 and cfg.runtime.odometry_checks.child_frame_id == "imu_link"
    with pytest.raises(ConfigError, match=r"zenoh\.listen"):
        load_config(None, ["zenoh.listen=[localhost:7447]"])
    with pytest.raises(ConfigError, match=r"unknown key .runtime\.queue_size."):
        load_config(None, ["runtime.queue_size=3"])
    with pytest.raises(ConfigError, match="odometry_queue_capacity"):
        load_config(None, ["runtime.odometry_queue_capacity=0"])
