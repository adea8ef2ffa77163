"""The onboard node's lifecycle: what configure and activate acquire is released in reverse
order on every path (a transition failing half-way, a normal shutdown)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from litevloc.config import load_config
from litevloc.runtime.service import app as app_mod
from litevloc.runtime.service.lifecycle import Lifecycle, LifecycleError, LifecycleState
from tests.runtime.fakes import SyntheticSource


class Boom(RuntimeError):
    pass


class Resources:
    """Fake resources that log their opening and closing; opening `fail_at` raises."""

    def __init__(self, fail_at: str | None = None) -> None:
        self.fail_at, self.log = fail_at, []  # type: list[str]

    def open(self, name: str) -> Any:
        if name == self.fail_at:
            raise Boom(f"{name} cannot open")
        self.log.append(f"open {name}")
        res = self

        class Handle:
            def close(self) -> None:
                res.log.append(f"close {name}")

        return Handle()

    def closed(self) -> list[str]:
        return [e.split(" ", 1)[1] for e in self.log if e.startswith("close ")]


class Node(Lifecycle):
    def __init__(self, res: Resources) -> None:
        super().__init__()
        self.res = res

    def on_configure(self) -> None:
        for name in ("a", "b", "c"):
            self.hold(self.res.open(name))

    def on_activate(self) -> None:
        self.hold(self.res.open("d"))

    def on_deactivate(self) -> None:
        self.res.log.append("deactivated")


@pytest.mark.parametrize(("fail_at", "released"), [
    ("a", []), ("b", ["a"]), ("c", ["b", "a"]),  # configure fails half-way
    ("d", ["c", "b", "a"]),  # activate fails: everything configure took goes too
])
def test_a_failed_transition_releases_what_it_had_newest_first(fail_at: str, released: list[str]) -> None:
    res = Resources(fail_at)
    node = Node(res)
    with pytest.raises(Boom):
        node.configure()
        node.activate()
    assert res.closed() == released and node.state is LifecycleState.UNCONFIGURED
    node.cleanup()  # nothing twice
    assert res.closed() == released


def test_shutdown_deactivates_then_releases_newest_first() -> None:
    res = Resources()
    with Node(res) as node:
        node.configure()
        node.activate()
        assert node.state is LifecycleState.ACTIVE and res.closed() == []
    assert res.log == ["open a", "open b", "open c", "open d", "deactivated",
                       "close d", "close c", "close b", "close a"]
    assert node.state is LifecycleState.UNCONFIGURED


def test_transitions_out_of_order_are_refused() -> None:
    node = Node(Resources())
    with pytest.raises(LifecycleError, match="cannot activate a node that is unconfigured"):
        node.activate()
    node.configure()
    with pytest.raises(LifecycleError, match="cannot configure a node that is inactive"):
        node.configure()


# ---------------------------------------------------------------------- the onboard node (build_app)
def fake_app_resources(monkeypatch: pytest.MonkeyPatch, res: Resources) -> None:
    """The VLoc process, the Zenoh session, the publisher and the /initialpose input as fakes."""

    def maker(name: str) -> Any:
        def make(*_: Any, **__: Any) -> Any:
            handle = res.open(name)
            handle.provider_report = None  # the VLoc process: its child's models (none here)
            handle.rmw_zenoh = False  # the bus
            return handle

        return make

    monkeypatch.setattr(app_mod, "VlocProcess", maker("vloc_process"))
    monkeypatch.setattr(app_mod, "Bus", maker("bus"))
    monkeypatch.setattr(app_mod, "LiteVLocPublisher", maker("publisher"))
    monkeypatch.setattr(app_mod, "InitialPoseInput", maker("initial_pose"))
    monkeypatch.setattr(app_mod, "read_manifest", lambda _: {"nodes": 3})


def build(tmp_path: Path) -> app_mod.App:
    (tmp_path / "manifest.json").write_text('{"nodes": 3}')  # `map_id` hashes it
    cfg = load_config("default", ["runtime.mode=realtime", "runtime.vloc_process=true",
                                  "zenoh.initial_pose.enabled=true"])
    return app_mod.build_app(cfg, tmp_path, SyntheticSource(seconds=0.1), 0.0)


@pytest.mark.parametrize(("fail_at", "released"), [
    ("bus", ["vloc_process"]),
    ("publisher", ["bus", "vloc_process"]),
    ("initial_pose", ["publisher", "bus", "vloc_process"]),  # activate
])
def test_build_app_failing_half_way_releases_in_reverse(monkeypatch: pytest.MonkeyPatch, tmp_path: Path,
                                                        fail_at: str, released: list[str]) -> None:
    res = Resources(fail_at)
    fake_app_resources(monkeypatch, res)
    with pytest.raises(Boom):
        build(tmp_path)
    assert res.closed() == released


def test_app_close_releases_in_reverse_after_a_run(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    res = Resources()
    fake_app_resources(monkeypatch, res)
    app = build(tmp_path)
    assert app.state is LifecycleState.ACTIVE and "initial_pose" in app.service.inputs
    app.close()
    assert res.closed() == ["initial_pose", "publisher", "bus", "vloc_process"]
    assert app.service.stop_event.is_set()  # deactivate stopped the service
