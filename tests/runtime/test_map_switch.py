"""Switching the running service's map version (`runtime.service.map_switch`): loaded beside the map in
use, switched to between two VLoc queries only, refused versions counted and reported with their kind,
and the localizer's tracking carried over; with fakes (no models, no map)."""

from __future__ import annotations

import threading
import time
import types
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from litevloc.base.params.localization import LocalizationParams
from litevloc.config.schema import DiagnosticsConfig
from litevloc.pipelines.localization.tracker import HeldPose, Tracker
from litevloc.pipelines.localization.tracking import TrackingState
from litevloc.pipelines.topomap.frame_check import frame_agreement
from litevloc.runtime.service.diagnostics import OK, WARN, map_status
from litevloc.runtime.service.map_switch import MapSwitcher, MapVersion
from litevloc.runtime.service.map_versions import MapRefusal, MapRefused, switch_localizer


class FakeBackend:
    """A switchable VLoc callable: records the order of queries and commits, loads in `load_s`."""

    def __init__(self, load_s: float = 0.0, query_s: float = 0.0) -> None:
        self.load_s, self.query_s = load_s, query_s
        self.events: list[str] = []
        self.in_query = False
        self.map = "v1"
        self.prepared: str | None = None
        self.refuse: dict[str, MapRefusal] = {}

    def __call__(self, frame: Any, prior: Any) -> str:
        self.in_query = True
        self.events.append(f"query:{self.map}")
        time.sleep(self.query_s)
        self.in_query = False
        return self.map

    def prepare_map(self, path: Path) -> int:
        time.sleep(self.load_s)
        if path.name in self.refuse:
            raise MapRefused(self.refuse[path.name], f"{path.name} is bad")
        self.prepared = path.name
        return 7

    def commit_map(self) -> None:
        assert not self.in_query and self.prepared is not None  # never inside a query
        self.events.append(f"commit:{self.prepared}")
        self.map, self.prepared = self.prepared, None

    def discard_map(self) -> None:
        self.prepared = None


def switcher(backend: FakeBackend) -> MapSwitcher:
    return MapSwitcher(backend, MapVersion(Path("/maps/v1"), "office", "v1", "v1@abc", 5),
                       map_id_of=lambda p: f"{p.name}@id")


def test_a_version_is_loaded_aside_and_switched_to_at_the_next_query() -> None:
    b = FakeBackend(load_s=0.2)
    sw = switcher(b)
    assert sw(None, None) == "v1"
    t0 = time.monotonic()
    sw.request(Path("/maps/v2"), "office", "v2")
    assert time.monotonic() - t0 < 0.1  # non-blocking: the load runs in the loader thread
    assert sw(None, None) == "v1"  # still loading: the map in use answers
    assert sw.wait_ready(5.0) and sw.ready is not None and sw.ready.version == "v2"
    assert b.events == ["query:v1", "query:v1"]  # prepared, not switched until the next query
    assert sw(None, None) == "v2"
    assert b.events[-2:] == ["commit:v2", "query:v2"]
    r = sw.report()
    assert (r["name"], r["version"], r["map_id"], r["nodes"]) == ("office", "v2", "v2@id", 7)
    assert (r["requests"], r["switches"], r["refusals"]) == (1, 1, 0)
    assert r["last_switch_s"] is not None and r["last_switch_s"] >= 0.2 and r["last_switch_wall"] is not None
    assert r["pending"] is None and r["loading"] is None and r["last_refusal"] is None
    sw.close()


def test_a_switch_never_happens_inside_a_query() -> None:
    b = FakeBackend(query_s=0.05)
    sw = switcher(b)
    stop = threading.Event()

    def queries() -> None:
        while not stop.is_set():
            sw(None, None)

    th = threading.Thread(target=queries)
    th.start()
    for v in ("v2", "v3", "v4"):
        sw.request(Path(f"/maps/{v}"), "office", v)
        assert sw.wait_ready(5.0)
        deadline = time.monotonic() + 5
        while sw.ready is not None and time.monotonic() < deadline:
            time.sleep(0.01)
    stop.set()
    th.join()
    assert [e for e in b.events if e.startswith("commit")] == ["commit:v2", "commit:v3", "commit:v4"]
    # every query after a commit runs on the map committed
    for i, e in enumerate(b.events):
        if e.startswith("commit") and i + 1 < len(b.events):
            assert b.events[i + 1] == f"query:{e.split(':')[1]}"
    sw.close()


@pytest.mark.parametrize("kind", list(MapRefusal))
def test_a_refused_version_is_counted_reported_and_the_map_kept(kind: MapRefusal) -> None:
    b = FakeBackend()
    b.refuse["bad"] = kind
    sw = switcher(b)
    sw.request(Path("/maps/bad"), "office", "v2")
    assert sw.wait_ready(5.0)
    assert sw.ready is None and sw(None, None) == "v1" and b.events == ["query:v1"]
    r = sw.report()
    assert (r["version"], r["switches"], r["refusals"]) == ("v1", 0, 1)
    assert r["last_refusal"] == kind.value and r["last_refused_version"] == "v2" and r["refused_since_switch"]
    lvl, name, msg, _, values = map_status(r, "", None, "hw")
    assert lvl == WARN and name == "litevloc/map" and kind.value in msg and ("last_refusal", kind.value) in values
    # the next good version is switched to, and the warning ends
    sw.request(Path("/maps/v3"), "office", "v3")
    assert sw.wait_ready(5.0) and sw(None, None) == "v3"
    r = sw.report()
    assert r["switches"] == 1 and r["refusals"] == 1 and not r["refused_since_switch"]
    assert r["last_refusal"] == kind.value  # the last refusal stays on record
    assert map_status(r, "", None, "hw")[0] == OK
    sw.close()


def test_the_newest_request_wins_over_one_waiting() -> None:
    b = FakeBackend(load_s=0.3)
    sw = switcher(b)
    sw.request(Path("/maps/v2"), "office", "v2")
    time.sleep(0.05)  # v2 is loading
    sw.request(Path("/maps/v3"), "office", "v3")
    sw.request(Path("/maps/v4"), "office", "v4")  # replaces v3, not yet taken
    assert sw.wait_ready(5.0)
    sw(None, None)  # commits v2, the one that was loading
    assert sw.wait_ready(5.0)
    sw(None, None)
    assert [e for e in b.events if e.startswith("commit")] == ["commit:v2", "commit:v4"]
    assert sw.report()["requests"] == 3 and sw.report()["version"] == "v4"
    sw.close()


def test_diagnostics_without_a_map_entry_keep_the_start_up_id() -> None:
    from litevloc.runtime.service.diagnostics import diagnostic_statuses

    out = diagnostic_statuses({"state": "TRACKING"}, None, DiagnosticsConfig(), "m@123", 9)
    assert next(s for s in out if s[1] == "litevloc/map")[4] == [("map_id", "m@123"), ("nodes", "9")]
    st = {"state": "TRACKING", "map": {"map_id": "m2@456", "name": "office", "version": "v2", "nodes": 11,
                                       "switches": 1, "refusals": 0}}
    entry = next(s for s in diagnostic_statuses(st, None, DiagnosticsConfig(), "m@123", 9) if s[1] == "litevloc/map")
    assert entry[0] == OK and entry[2] == "office@v2"
    assert ("map_id", "m2@456") in entry[4] and ("nodes", "11") in entry[4]


def _pose(x: float, yaw_deg: float = 0.0) -> np.ndarray:
    T = np.eye(4)
    c, s = np.cos(np.radians(yaw_deg)), np.sin(np.radians(yaw_deg))
    T[:2, :2] = [[c, -s], [s, c]]
    T[0, 3] = x
    return T


class _Map:
    def __init__(self, t_ns: list[int], poses: list[np.ndarray]) -> None:
        self.t_ns, self.T_map_camera = np.array(t_ns, np.int64), np.stack(poses)


def test_frame_agreement_compares_the_keyframes_both_versions_hold() -> None:
    old = _Map([1, 2, 3], [_pose(0), _pose(1), _pose(2)])
    same = _Map([2, 3, 9], [_pose(1.01), _pose(2), _pose(7)])  # one re-optimised by 1 cm, one new
    a = frame_agreement(old, same)
    assert a.shared == 2 and a.median_m == pytest.approx(0.005) and a.agrees(0.1, 2.0)
    moved = _Map([1, 2, 3], [_pose(1), _pose(2, 5), _pose(3)])  # another frame: 1 m off
    b = frame_agreement(old, moved)
    assert b.shared == 3 and b.median_m == pytest.approx(1.0) and not b.agrees(0.1, 2.0)
    disjoint = frame_agreement(old, _Map([7, 8], [_pose(0), _pose(0)]))
    assert disjoint.shared == 0 and disjoint.agrees(0.1, 2.0)


def test_a_tracker_continues_the_old_ones_tracking() -> None:
    p = LocalizationParams()
    old = Tracker(p, None, None)
    old.state, old.failures, old.last_pose, old.last_pose_t_ns = TrackingState.TRACKING, 1, _pose(3), 42
    old.held = HeldPose(40, _pose(3.1), _pose(3))
    old.ll_wall_ms.extend([10.0, 12.0])
    new = Tracker(p, None, None)
    new.carry_over(old, 50, "map version switched")
    assert new.state is TrackingState.TRACKING and new.failures == 1 and new.last_pose_t_ns == 42
    assert np.array_equal(new.last_pose, _pose(3)) and new.held is old.held and list(new.ll_wall_ms) == [10.0, 12.0]
    assert new.transitions[-1].reason == "map version switched" and new.transitions[-1].t_ns == 50


def test_the_switch_logs_the_ll_failures_it_carries(caplog: pytest.LogCaptureFixture) -> None:
    p = LocalizationParams()
    old, new = Tracker(p, None, None), Tracker(p, None, None)
    old.state, old.failures = TrackingState.TRACKING, 2
    with caplog.at_level("INFO", logger="litevloc.runtime.service.map_versions"):
        got = switch_localizer(types.SimpleNamespace(tracker=old), types.SimpleNamespace(tracker=new), 7)
    assert got.tracker is new and new.failures == 2
    assert f"TRACKING, 2 consecutive LL failures (LOST at {p.local_search.failures_before_lost})" in caplog.text
