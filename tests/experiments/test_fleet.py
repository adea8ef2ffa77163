"""The fleet benchmark's JSON entry (experiments/fleet.py) built from recorded figures, the pose step
at the switch and the push's figures; bench/fleet.py's smallest run end to end on the simulated
office (its inputs rendered once by experiments/fleet_inputs.py and cached under out/test_cache)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from litevloc.experiments.fleet import (
    CONTRACT_KEYS,
    PUSH_KEYS,
    PoseTrack,
    PushFigures,
    RobotFigures,
    control_entry,
    error_split,
    fleet_entry,
    fleet_estimate,
    lost_spans,
    max_step_m,
    push_entry,
    spans_not_in,
)
from litevloc.experiments.fleet_inputs import SimFleetInputs

ROOT = Path(__file__).resolve().parents[2]
ANNOUNCE = 1000.0


def _robot(switch: float | None = 1001.5, vloc: int = 17, cpu: float = 14.5, lost: int = 0) -> RobotFigures:
    return RobotFigures(vloc_calls=vloc, stream_s=14.5, cpu_s=cpu, switch_wall=switch, lost=lost, jump_m=0.004,
                        first_lost_after_switch_s=None if not lost else 7.0,
                        step_m=0.005, wire_bytes=1_200_000, wire_bytes_by_topic={"litevloc/pose": 1_000_000,
                                                                                 "litevloc/status": 200_000})


def _entry(robots: list[RobotFigures], announce: float | None = ANNOUNCE) -> dict:
    return fleet_entry(robots, fetch_s=0.64, fetch_bytes=2_371_262, announce_wall=announce, server_rss_mb=133.0,
                       server_cpu_s=0.4, run_s=40.0)


def test_entry_has_the_contract_keys_and_the_figures_of_its_robots() -> None:
    e = _entry([_robot(1001.5), _robot(1003.0, vloc=10, cpu=20.0, lost=2)])
    assert set(CONTRACT_KEYS) <= set(e)
    assert e["robots"] == 2 and e["robots_switched"] == 2
    assert e["switch_s_max"] == pytest.approx(3.0)  # the announcement to the last robot switched
    assert e["switch_s_per_robot"] == pytest.approx([1.5, 3.0])
    assert e["lost_during_switch"] == 2 and e["lost_after_announce_per_robot"] == [0, 2]
    assert e["first_lost_after_switch_s"] == [None, 7.0]
    assert e["vloc_hz_per_robot"] == pytest.approx([17 / 14.5, 10 / 14.5])
    assert e["cpu_s_per_vloc"] == pytest.approx([14.5 / 17, 2.0])
    assert e["wire_bytes_per_robot_per_min"] == pytest.approx(60 * 1_200_000 / 14.5)
    assert e["wire_bytes_per_min_by_topic"]["litevloc/pose"] == pytest.approx(60 * 1_000_000 / 14.5)
    assert e["server_cpu_percent"] == pytest.approx(1.0)
    json.dumps(e, allow_nan=False)  # what write_json writes: plain JSON


def test_a_robot_that_did_not_switch_leaves_no_switch_time() -> None:
    e = _entry([_robot(1001.5), _robot(None)])
    assert e["switch_s_max"] is None and e["robots_switched"] == 1
    assert _entry([_robot()], announce=None)["switch_s_max"] is None
    assert _entry([_robot(vloc=0)])["cpu_s_per_vloc"] == [None]


def test_estimate_scales_the_steady_state_per_robot() -> None:
    e = _entry([_robot(), _robot()])
    one = {**_entry([_robot()]), "server_rss_mb": 123.0}
    est = fleet_estimate([one, e], robots=50)
    assert est["router_bytes_per_s"] == pytest.approx(50 * e["wire_bytes_per_robot_per_min"] / 60)
    assert est["server_cpu_percent"] == pytest.approx(1.0 / 2 * 50)
    assert est["all_fetch_s_at_measured_rate"] == pytest.approx(50 * 0.64)
    slow = {**e, "wire_bytes_per_robot_per_min_real_time": 5 * e["wire_bytes_per_robot_per_min"]}  # rate 0.2
    assert fleet_estimate([one, slow], robots=50)["router_bytes_per_s"] == pytest.approx(
        5 * est["router_bytes_per_s"])
    assert est["server_rss_mb_per_robot"] == pytest.approx(10.0)  # 123 MB with one robot, 133 with two
    assert est["server_rss_mb"] == pytest.approx(133.0 + 48 * 10.0)


def test_max_step_is_the_largest_consecutive_step_in_the_window() -> None:
    tr = PoseTrack()
    for i, x in enumerate([0.0, 0.01, 0.02, 0.12, 0.13]):  # a 10 cm step between t=2 and t=3
        tr.add(float(i), (x, 0.0, 0.0))
    assert max_step_m(tr, 0.0, 4.0) == pytest.approx(0.10)
    assert max_step_m(tr, 0.0, 2.0) == pytest.approx(0.01)
    assert max_step_m(tr, 3.5, 4.0) is None


def test_error_split_matches_ground_truth_stamps_and_splits_at_the_switch() -> None:
    gt = {1000: (0.0, 0.0, 0.0), 2000: (1.0, 0.0, 0.0), 3000: (2.0, 0.0, 0.0), 9_000_000_000: (5.0, 0.0, 0.0)}
    # fused poses: stamp 1001 is 2 cm off, 1990 (nearest to 2000) 4 cm off, 2500 is no GT's nearest,
    # 3000 (received after the switch at wall 10) 10 cm off; no pose near the last GT stamp
    poses = [(1.0, 1001, (0.02, 0.0, 0.0)), (2.0, 1990, (1.04, 0.0, 0.0)), (3.0, 2500, (9.0, 0.0, 0.0)),
             (11.0, 3000, (2.0, 0.1, 0.0))]
    e = error_split(poses, gt, split_wall=10.0)
    assert (e.n_before, e.n_after) == (2, 1)
    assert e.before_m == pytest.approx(0.03) and e.after_m == pytest.approx(0.1)
    assert error_split(poses, gt, None).n_after == 0
    assert error_split([], gt, 10.0).before_m is None


def _push(published: bool | None = True, announce: float | None = 1060.0) -> PushFigures:
    return PushFigures(start_wall=1000.0, verdict_wall=1059.9, published=published, reason="held-out check ...",
                       announce_wall=announce, exit_code=0 if published else 1, bytes=16_000_000,
                       details={"candidate": {"accepted": 2}})


def test_push_entry_times_the_push_and_the_last_switch() -> None:
    e = push_entry(_push(), [1061.0, 1063.5])
    assert set(PUSH_KEYS) <= set(e)
    assert e["push_s"] == pytest.approx(60.0) and e["push_verdict_s"] == pytest.approx(59.9)
    assert e["push_to_all_switched_s"] == pytest.approx(63.5)
    assert e["push_published"] is True and e["push_details"] == {"candidate": {"accepted": 2}}
    json.dumps(e, allow_nan=False)


def test_push_entry_of_a_refused_or_unfinished_push_or_none() -> None:
    refused = push_entry(_push(False, None), [None, None])
    assert refused["push_s"] is None and refused["push_to_all_switched_s"] is None
    assert refused["push_published"] is False and refused["push_verdict_s"] == pytest.approx(59.9)
    # published, but one robot never switched, or switched before the announcement (not to this version)
    assert push_entry(_push(), [1061.0, None])["push_to_all_switched_s"] is None
    assert push_entry(_push(), [1061.0, 1059.0])["push_to_all_switched_s"] is None
    none = push_entry(None, [None])
    assert set(PUSH_KEYS) <= set(none) and none["push_published"] is None and "no push" in none["push_reason"]


@pytest.mark.slow
@pytest.mark.timeout(420)
@pytest.mark.skipif(not os.environ.get("LITEVLOC_LONG_TESTS"),
                    reason="~3 CPU-min to render its simulated office plus ~100 s of push and switch on 2 CPUs, "
                    "over the suite's budget: set LITEVLOC_LONG_TESTS=1 to run it")
def test_smallest_fleet_run_writes_the_contract(sim_fleet: SimFleetInputs, tmp_path: Path) -> None:
    out = tmp_path / "fleet.json"
    ins = sim_fleet
    subprocess.run([sys.executable, str(ROOT / "bench" / "fleet.py"), "--robots", "1", "--quick", "--json", str(out),
                    "--v1", str(ins.v1), "--rec", str(ins.rec), "--push", str(ins.push), "--held-out",
                    str(ins.held_out)], check=True, timeout=400)
    e = json.loads(out.read_text())["runs"][0]
    assert set(CONTRACT_KEYS) <= set(e) and set(PUSH_KEYS) <= set(e) and e["robots"] == 1
    assert e["fetch_bytes"] > 0 and e["vloc_hz_per_robot"][0] > 0
    assert e["fused_error_m_before_switch"][0] is not None and e["fused_error_m_before_switch"][0] < 0.5
    # robot0's push was decided by the held-out gate, either way, with its reason and figures
    assert isinstance(e["push_published"], bool) and e["push_reason"] and e["push_verdict_s"] > 0
    assert e["push_exit_code"] == (0 if e["push_published"] else 1)
    if e["push_published"]:
        assert e["push_s"] > 0 and {"current", "candidate", "build"} <= set(e["push_details"])
    else:
        assert e["push_s"] is None and e["robots_switched"] == 0
    if e["robots_switched"]:  # the version switched to is the pushed one, announced after the push began
        assert e["push_published"] and e["lost_during_switch"] == 0
        assert e["push_to_all_switched_s"] == pytest.approx(e["push_s"] + e["switch_s_max"])


def test_lost_spans_join_close_stamps_and_split_at_gaps() -> None:
    s = 10**9
    start = 5 * s
    # out of order; 0.5 s apart joins, 2 s apart splits; one stamp alone is a span of zero length
    stamps = [start + 3 * s, start + int(3.5 * s), start + 4 * s, start + 9 * s, start + 6 * s]
    assert lost_spans(stamps, start) == [(3.0, 4.0), (6.0, 6.0), (9.0, 9.0)]
    assert lost_spans(stamps, start, gap_s=3.0) == [(3.0, 9.0)]
    assert lost_spans([], start) == []


def test_spans_not_in_the_control_are_the_runs_own_lost_stretches() -> None:
    control = [(2.4, 2.7), (13.4, 13.7), (38.3, 39.7)]
    run = [(2.6, 2.8), (14.4, 14.7), (20.0, 21.0), (38.3, 39.7)]
    # 14.4 lies within the tolerance of the control's 13.7: the same stretch a frame later
    assert spans_not_in(run, control) == [(20.0, 21.0)]
    assert spans_not_in(run, control, tolerance_s=0.0) == [(14.4, 14.7), (20.0, 21.0)]
    assert spans_not_in(run, []) == run
    entry = control_entry({"lost_spans_s_per_robot": [[list(s) for s in run], []]},
                          {"lost_spans_s_per_robot": [[list(s) for s in control], [[1.0, 2.0]]]})
    assert entry["lost_spans_not_in_control_per_robot"] == [[[20.0, 21.0]], []]
    assert entry["control_lost_spans_s_per_robot"][1] == [[1.0, 2.0]]
