"""`litevloc run` in realtime mode on the real stack (issue 19, item 8).

The deployment path end to end, nothing faked: the service is a `litevloc run` process
(realtime mode: threads, latest-frame mailbox) with the real ONNX models and the default
matcher (ALIKED + LightGlue), real GTSAM fusion, and odometry that arrives over Zenoh from
this (second) process, which also receives the fused poses and the status over Zenoh.
Queries are held-out 7-Scenes frames (500:1000:10, 50 frames, 16.3 s of sensor time) in a map
built from the mapping pass only (frames 0:500:5); both are the suite's shared, cached inputs
(`seven_scenes_held_out` in tests/conftest.py; ~2-3 min once; the test itself ~1 min: the
recording plays at RATE).

Checked: the fused base pose against ground truth; LOST driven by the real localizer (camera
frames withheld for 4 s: no fix is accepted, the state goes LOST and poses are withheld), then
recovery by local localization from the fused prior; and a clean SIGTERM shutdown (exit 0,
reason SIGTERM, every stage stopped). A `depth_invalid` window instead (the localizer rejects
every frame) was tried: the localizer then falls back to global localization, which on a loaded
2-CPU machine took up to 30 s of wall time to re-localize, too slow for a bounded test.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from litevloc.base.geometry import interpolate_pose_at, invert, relative_pose_error
from litevloc.config import load_config
from litevloc.config.schema import ZenohConfig
from litevloc.hw import ros_msgs
from litevloc.hw.messages import GroundTruthPose, Odometry
from litevloc.hw.odometry import OdometrySender
from litevloc.hw.streams.mcap_io import McapSource
from litevloc.runtime.transport.bus import TOPICS, Bus, topic_key, warm_codecs
from tests.conftest import HeldOut

from .zenoh_helpers import free_port

# Sensor seconds from the first message: no camera frame in [3.5, 7.5) s; LOST after 2.5 s without a fix.
FAULT_START_S, FAULT_END_S = 3.5, 7.5
FAULT = f"camera_dropout@{FAULT_START_S:g}:{FAULT_END_S - FAULT_START_S:g}"
LOST_AFTER_S = 2.5
# SIGTERM once fused poses have arrived up to this sensor time (re-localized for 2 s after the fault),
# or at the latest when the odometry sent reaches END_S (the recording runs 16.3 s: stop before its end).
STOP_AT_S, END_S = FAULT_END_S + 3.0, 15.5
ODOM_LEAD_S = 0.3  # sensor s: odometry is sent this far ahead of the replayed camera (fusion buffers 5 s)
# Playback speed of the recording (camera and odometry alike). Realtime mode either way (threads,
# latest-frame mailbox dropping stale frames); below 1 so that VLoc, which takes 0.3-0.5 s per frame
# on an idle 2-CPU machine and several times that on a shared, loaded one, still gets a fix every
# sensor second or so and the LOST window is told apart from slowness.
RATE = 0.2
# The service's VLoc thread runs at nice 10 (runtime.vloc_nice) to keep fusion latency low inside
# the service; on a shared test machine that starves it behind every other process, so nice 0 here.
VLOC_NICE = 0

pytestmark = [pytest.mark.shared_data, pytest.mark.slow]


@pytest.fixture(scope="module")
def inputs(seven_scenes_held_out: HeldOut) -> tuple[Path, Path]:
    """(map folder, query recording): the held-out inputs the suite shares (tests/conftest.py)."""
    return seven_scenes_held_out.map_dir, seven_scenes_held_out.queries


class Robot:
    """This process's side: sends the recording's odometry over Zenoh, paced at real time and
    started when the service's first status arrives; records fused poses and status states."""

    def __init__(self, bus: Bus, odometry: list[Odometry]) -> None:
        self.bus, self.odometry = bus, odometry
        self.t0_ns = odometry[0].t_ns
        self.poses: list[tuple[int, np.ndarray]] = []
        self.states: list[tuple[float, str, dict[str, Any]]] = []
        self.started = threading.Event()
        self.stop = threading.Event()
        self.late_pose = threading.Event()
        self.near_end = threading.Event()
        self.lock = threading.Lock()
        self.sent = 0
        self.subs = [bus.subscribe(topic_key("", "pose"), self._on_pose),
                     bus.subscribe(topic_key("", "status"), self._on_status)]
        self.thread = threading.Thread(target=self._send, daemon=True)
        self.thread.start()

    def _on_pose(self, sample: Any) -> None:
        t_ns, T, _ = ros_msgs.odometry_to_matrix(ros_msgs.deserialize(sample.payload.to_bytes(), TOPICS["pose"][1]))
        with self.lock:
            self.poses.append((t_ns, T))
        if t_ns - self.t0_ns >= STOP_AT_S * 1e9:
            self.late_pose.set()

    def _on_status(self, sample: Any) -> None:
        st = json.loads(ros_msgs.deserialize(sample.payload.to_bytes(), TOPICS["status"][1]).data)
        with self.lock:
            self.states.append((time.monotonic(), st["state"], st))
        self.started.set()

    def _send(self) -> None:
        tx = OdometrySender(self.bus.session, "odom")
        if not self.started.wait(300):
            return
        wall0 = time.monotonic() - ODOM_LEAD_S / RATE
        for odom in self.odometry:
            due = wall0 + (odom.t_ns - self.t0_ns) * 1e-9 / RATE
            if self.stop.wait(max(0.0, due - time.monotonic())):
                return
            tx.send(odom)
            self.sent += 1
            if odom.t_ns - self.t0_ns >= END_S * 1e9:
                self.near_end.set()

    def close(self) -> None:
        self.stop.set()
        self.thread.join(5)
        for s in self.subs:
            s.undeclare()


def _pose_errors(poses: list[tuple[int, np.ndarray]], gt: list[GroundTruthPose],
                 T_base_camera: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(stamps s from the first GT, position error m, rotation error deg) of the fused T_map_base
    against ground truth interpolated at each stamp (poses inside the GT time span only)."""
    t_gt = np.array([g.t_ns for g in gt], dtype=np.int64)
    T_gt = np.stack([g.T_world_camera for g in gt])
    ts, dts, drs = [], [], []
    for t_ns, T in poses:
        if t_gt[0] <= t_ns <= t_gt[-1]:
            T_true = interpolate_pose_at(t_ns, t_gt, T_gt) @ invert(T_base_camera)
            dt, dr = relative_pose_error(T, T_true)
            ts.append((t_ns - t_gt[0]) * 1e-9)
            dts.append(dt)
            drs.append(dr)
    return np.array(ts), np.array(dts), np.array(drs)


@pytest.mark.timeout(900)
def test_realtime_run_on_held_out_queries(inputs: tuple[Path, Path], tmp_path: Path) -> None:
    map_dir, rec = inputs
    msgs = list(McapSource(rec))
    odometry = [m for m in msgs if isinstance(m, Odometry)]
    gt = [m for m in msgs if isinstance(m, GroundTruthPose)]
    assert len(odometry) > 1500 and len(gt) == 50
    warm_codecs()
    ep = f"tcp/127.0.0.1:{free_port()}"
    out = tmp_path / "run.json"
    with Bus(ZenohConfig(listen=(ep,))) as bus:
        robot = Robot(bus, odometry)
        cmd = [sys.executable, "-m", "litevloc.cli.main", "run", "--config", "7scenes", "--map", str(map_dir),
               "--source", str(rec), "--rate", str(RATE), "--listen", f"tcp/127.0.0.1:{free_port()}", "--connect", ep,
               "--fault", FAULT, "--json", str(out),
               "--set", "runtime.mode=realtime", "--set", "runtime.odometry_input=zenoh",
               "--set", "runtime.lost_policy=withhold", "--set", f"runtime.lost_after_s={LOST_AFTER_S}",
               "--set", "runtime.status_period_s=0.2", "--set", f"runtime.vloc_nice={VLOC_NICE}"]
        log = tmp_path / "run.log"
        with log.open("w") as f:
            proc = subprocess.Popen(cmd, stdout=f, stderr=subprocess.STDOUT, text=True)
            try:
                t_end = time.monotonic() + 600
                while not (robot.late_pose.wait(0.2) or robot.near_end.is_set()) and proc.poll() is None \
                        and time.monotonic() < t_end:
                    pass
                got_late = robot.late_pose.is_set()
                sent_at_stop = robot.sent
                proc.send_signal(signal.SIGTERM)
                rc = proc.wait(timeout=60)
            finally:
                if proc.poll() is None:
                    proc.kill()
                    proc.wait()
                robot.close()
    text = log.read_text()
    seen = f"{len(robot.poses)} poses, last at {(robot.poses[-1][0] - robot.t0_ns) * 1e-9 if robot.poses else 0:.2f} s"
    assert got_late, (f"no fused pose reached {STOP_AT_S} s of the recording ({seen}, states "
                      f"{[s for _, s, _ in robot.states][-20:]}, {robot.sent} odometry sent); log:\n{text[-3000:]}\n"
                      f"{out.read_text()[-3000:] if out.is_file() else ''}")
    # clean SIGTERM shutdown
    assert rc == 0, text[-3000:]
    res = json.loads(out.read_text())
    st = res["status"]
    assert res["ok"] and res["reason"] == "SIGTERM", res["reason"]
    assert all(s["state"] in ("STOPPED", "DONE") and not s["alive"] for s in st["stages"].values()), st["stages"]
    # odometry came over Zenoh from this process (the recording's own was ignored); none lost silently: all
    # that was sent up to SIGTERM arrived (but the last 0.1 s in flight) and all that arrived was fused, but for
    # what arrived as the service stopped (counted: left in its queue, or refused by the closed queue)
    c, odo = st["counters"], st["odometry"]
    assert c["odometry_ignored"] > 0 and odo["skipped_total"] == 0 and odo["gaps"] == 0, odo
    assert sent_at_stop - 2 <= odo["accepted"] <= robot.sent and sent_at_stop > 900, (sent_at_stop, odo["accepted"])
    at_stop = c["odometry_left_at_stop"] + odo["sink_errors"]
    assert c["odometry_fused"] + at_stop == odo["accepted"] and at_stop <= 5 and c["odometry_rejected"] == 0, (c, odo)
    # the real localizer: fixes accepted (first, before and after the window); frames withheld in it
    print("counters:", c, "vloc latency:", st["stages"]["vloc"]["latency"])
    assert c["vloc_accepted"] >= 3 and st["faults"]["changed"]["camera_dropout"] >= 10, (c, st["faults"])
    # LOST driven by the localizer: withheld poses, a LOST status, then TRACKING again
    states = [s for _, s, _ in robot.states]
    assert "LOST" in states and c["poses_withheld"] > 0, (states, c)
    assert "TRACKING" in states[states.index("LOST"):], states
    # fused base pose vs ground truth (GT is the colour camera's; base_link from the config's T_base_camera)
    T_base_camera = load_config("7scenes").fusion.T_base_camera()
    t, err, err_deg = _pose_errors(robot.poses, gt, T_base_camera)
    print("published pose stamps per sensor second:", np.bincount(t.astype(int), minlength=17).tolist())
    print("states:", "".join(s[0] for s in states))
    assert len(err) > 150, len(err)  # measured ~270 on a loaded machine: first fix ~3 s, LOST ~6-10 s
    # withhold: no pose from LOST_AFTER_S after the fault began (+0.5 s slack) to its end
    assert not np.any((t >= FAULT_START_S + LOST_AFTER_S + 0.5) & (t < FAULT_END_S)), "poses published while LOST"
    after = err[t > FAULT_END_S + 1.0]  # re-localized after the fault window
    assert len(after) > 20, len(after)
    print(f"fused position error: median {np.median(err):.3f} m, p90 {np.percentile(err, 90):.3f} m, "
          f"max {err.max():.3f} m over {len(err)} poses; after recovery median {np.median(after):.3f} m; "
          f"rotation median {np.median(err_deg):.2f} deg, p90 {np.percentile(err_deg, 90):.2f} deg")
    # bounds ~4x the measured figures (median 2.4 cm, p90 5.9 cm, after recovery 4.4 cm)
    assert np.median(err) < 0.10 and np.percentile(err, 90) < 0.20 and np.median(after) < 0.10
    assert np.median(err_deg) < 5.0 and np.percentile(err_deg, 90) < 10.0
