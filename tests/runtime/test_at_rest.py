"""A robot at rest on a loaded onboard computer: the real service (map, ONNX models, GTSAM
fusion) in real time on one held-out 7-Scenes frame repeated, its odometry still, each VLoc call
made 4 s slower (`slow_vloc`, 8 s of sensor time at twice real time). Its fixes are more than
the 7.5 s apart after which time alone made a fused prior too old to confirm an LL pose: drift
comes with motion, so at rest the prior stays fresh, each fix is accepted at once and the fusion
starts on the second."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import pytest

from litevloc.cli.main import main
from litevloc.hw.messages import Message, Odometry, RgbdFrame
from litevloc.hw.streams.mcap_io import McapSource, record_messages
from tests.conftest import HeldOut

from .zenoh_helpers import free_port

SECONDS = 40.0  # of sensor time: ~20 s at twice real time


def _at_rest(src: Path, dst: Path) -> None:
    """The first frame of `src` at 10 Hz and its first odometry pose at 100 Hz for SECONDS."""
    first = next(m for m in McapSource(src) if isinstance(m, RgbdFrame))
    odo = next(m for m in McapSource(src) if isinstance(m, Odometry))

    def messages() -> Iterator[Message]:
        for k in range(int(SECONDS * 100)):
            t = first.t_ns + k * 10_000_000
            yield Odometry(t, odo.T_odom_base)
            if k % 10 == 0:
                yield RgbdFrame(t, first.color, first.depth, first.K, index=k // 10)

    record_messages(messages(), dst)


@pytest.mark.timeout(240)
def test_at_rest_with_a_slow_vloc_every_fix_is_accepted_and_fusion_starts(seven_scenes_held_out: HeldOut,
                                                                          tmp_path: Path) -> None:
    rec = tmp_path / "at_rest.mcap"
    _at_rest(seven_scenes_held_out.queries, rec)
    js = tmp_path / "r.json"
    rc = main(["replay", str(rec), "--config", "7scenes", "--map", str(seven_scenes_held_out.map_dir),
               "--rate", "2", "--fault", "slow_vloc@0:1000,delay_ms=4000", "--json", str(js),
               "--listen", f"tcp/127.0.0.1:{free_port()}"])
    assert rc == 0
    res = json.loads(js.read_text())
    c = res["counters"]
    # at least two fixes, every one accepted (none held for want of a fresh prior), and fused
    assert c["vloc_calls"] >= 2 and c["vloc_accepted"] == c["vloc_calls"], (c, res["reasons"])
    assert c["fusion_accepted"] >= 1 and res["fused_poses"] > 0, (c, res["reasons"])
