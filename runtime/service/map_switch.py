"""Switch the running service to a new version of its map without a restart.

```
request(path, name, version)   any thread, returns at once (the newest request wins)
  -> loader thread (at runtime.vloc_nice): backend.prepare_map(path)   load + verify beside the map in use
       refused: counted, logged, `last_refusal` set; the map in use stays
  -> VLoc thread, at the start of its next query: backend.commit_map()  the safe point
```

The safe point is the VLoc stage's own call: the service makes one VLoc query at a time from one
thread, so a switch made at the start of a call falls between two results, never inside a query.
The new localizer continues the old one's tracking (`Tracker.carry_over`: the state, the last pose
and the held pose, all in the map frame), and fusion is not touched: the fused pose and the prior
it gives the next query are in the map frame, which a version made by `map update` or `map merge`
keeps (checked: `pipelines.topomap.frame_check`). So the first query after the switch is LL around
the fused prior in the new version, and the fused pose goes on without a step. Node-id state (the
second look's per-node feature cache, the verifier's covisibility lists) is the new localizer's own.

The backend is the VLoc callable itself: `map_versions.ThreadVloc` (in this process) or
`vloc_process.VlocProcess` (the child loads and swaps; its pipe carries the commands).
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

from litevloc.runtime.service.map_versions import MapRefusal, MapRefused
from litevloc.runtime.service.stages import lower_thread_priority

if TYPE_CHECKING:
    from litevloc.hw.messages import RgbdFrame
    from litevloc.runtime.service.core import VlocOutcome
    from litevloc.runtime.service.vloc_prior import VlocPrior

log = logging.getLogger(__name__)


class SwitchableVloc(Protocol):
    """A VLoc callable that can load a map version beside its own and switch to it."""

    def __call__(self, frame: RgbdFrame, prior: VlocPrior | None) -> VlocOutcome: ...

    def prepare_map(self, path: Path) -> int: ...  # slow; node count, or MapRefused

    def commit_map(self) -> None: ...  # between two queries only

    def discard_map(self) -> None: ...


@dataclass(frozen=True)
class MapVersion:
    """One version of the map: its folder, name and version as the map service names them (None:
    not given, e.g. a folder handed to `litevloc run --map`), `map_id` (`app.map_id`) and node count."""

    path: Path
    name: str | None
    version: str | None
    map_id: str = ""
    nodes: int | None = None


class MapSwitcher:
    """The service's VLoc callable in front of a `SwitchableVloc`, and `request` to switch its map.

    `map_id_of(path)`: the id shown for a version (`app.map_id`); `nice`: the loader thread's nice."""

    def __init__(self, backend: SwitchableVloc, current: MapVersion, *, map_id_of: Any = None, nice: int = 0,
                 clock: Any = time.monotonic) -> None:
        self.backend, self.current, self.nice, self._clock = backend, current, nice, clock
        self._map_id_of = map_id_of
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._closed = threading.Event()
        self._requested: tuple[MapVersion, float] | None = None  # newest request not yet taken by the loader
        self._loading: MapVersion | None = None
        self._ready: tuple[MapVersion, float] | None = None  # prepared, switched to at the next query
        self._committed = threading.Condition(self._lock)
        self._thread: threading.Thread | None = None
        self.counters = {"requests": 0, "switches": 0, "refusals": 0}
        self.last_switch_wall: float | None = None  # time.time() of the last switch
        self.last_switch_s: float | None = None  # request -> switched, seconds
        self.last_refusal: MapRefusal | None = None
        self.last_refusal_detail: str | None = None
        self.last_refused_version: str | None = None
        self._refused_after_switch = False

    # ------------------------------------------------------------------ any thread
    def request(self, path: Path, name: str, version: str) -> None:
        """Switch to the version at `path` once it loaded and passed its checks (returns at once;
        thread-safe). A request waiting to be loaded is replaced by a newer one."""
        with self._lock:
            self.counters["requests"] += 1
            self._requested = (MapVersion(Path(path), name, version), self._clock())
            if self._thread is None:
                self._thread = threading.Thread(target=self._run, name="map-switch", daemon=True)
                self._thread.start()
        self._wake.set()

    def wait_ready(self, timeout_s: float) -> bool:
        """Wait until the loader has nothing it can do (each request prepared or refused, or waiting
        behind a prepared one); True if so within `timeout_s` (tests, the local trigger)."""
        deadline = self._clock() + timeout_s
        with self._lock:
            while self._loading is not None or (self._requested is not None and self._ready is None):
                left = deadline - self._clock()
                if left <= 0:
                    return False
                self._committed.wait(min(left, 0.05))
        return True

    @property
    def ready(self) -> MapVersion | None:
        """The version prepared and waiting for the next query (None: none)."""
        r = self._ready
        return None if r is None else r[0]

    def close(self) -> None:
        """End the loader thread (a load under way finishes in the background, then is dropped)."""
        self._closed.set()
        self._wake.set()

    # ------------------------------------------------------------------ the VLoc thread
    def __call__(self, frame: RgbdFrame, prior: VlocPrior | None) -> VlocOutcome:
        if self._ready is not None:  # the safe point: no query of either map is under way
            self._commit()
        return self.backend(frame, prior)

    def _commit(self) -> None:
        with self._lock:
            ready, self._ready = self._ready, None
            if ready is None:
                return
            version, t_request = ready
            try:
                self.backend.commit_map()
            except MapRefused as exc:  # the VLoc process died: its query reports that next
                self._refuse_locked(version, exc.kind, str(exc))
                return
            old, self.current = self.current, version
            self.counters["switches"] += 1
            self.last_switch_wall, self.last_switch_s = time.time(), self._clock() - t_request
            self._refused_after_switch = False
            self._committed.notify_all()
        log.info("map switched: %s -> %s (%s nodes, %.2f s after the request)", _label(old), _label(version),
                 version.nodes, self.last_switch_s)

    # ------------------------------------------------------------------ the loader thread
    def _run(self) -> None:
        lower_thread_priority(self.nice)
        while not self._closed.is_set():
            self._wake.wait()
            self._wake.clear()
            while not self._closed.is_set():
                with self._lock:
                    if self._ready is not None:  # the prepared one goes first (the backend holds one)
                        self._committed.wait(0.05)
                        continue
                    if self._requested is None:
                        break
                    (version, t_request), self._requested = self._requested, None
                    self._loading = version
                self._load(version, t_request)

    def _load(self, version: MapVersion, t_request: float) -> None:
        try:
            nodes = self.backend.prepare_map(version.path)
            map_id = self._map_id_of(version.path) if self._map_id_of is not None else ""
        except MapRefused as exc:
            self._refuse(version, exc.kind, str(exc))
            return
        except Exception as exc:  # a load that fails any other way is refused too: the map in use stays
            self._refuse(version, MapRefusal.LOAD_FAILED, f"{type(exc).__name__}: {exc}")
            return
        with self._lock:
            self._loading = None
            if self._closed.is_set():
                self.backend.discard_map()
            else:
                self._ready = (replace(version, map_id=map_id, nodes=nodes), t_request)
            self._committed.notify_all()
        log.info("map version %s loaded and verified (%d nodes): switching at the next VLoc query",
                 _label(version), nodes)

    def _refuse(self, version: MapVersion, kind: MapRefusal, detail: str) -> None:
        with self._lock:
            self._loading = None
            self._refuse_locked(version, kind, detail)

    def _refuse_locked(self, version: MapVersion, kind: MapRefusal, detail: str) -> None:
        self.counters["refusals"] += 1
        self.last_refusal, self.last_refusal_detail = kind, detail
        self.last_refused_version = version.version
        self._refused_after_switch = True
        self._committed.notify_all()
        log.warning("map version %s refused (%s): %s; keeping %s", _label(version), kind.value, detail,
                    _label(self.current))

    # ------------------------------------------------------------------ status
    def report(self) -> dict[str, Any]:
        """The status's `map` entry (JSON-able)."""
        with self._lock:
            cur, ready, loading = self.current, self._ready, self._loading
            return {
                "name": cur.name, "version": cur.version, "map_id": cur.map_id, "nodes": cur.nodes,
                "path": str(cur.path), **self.counters,
                "last_switch_wall": self.last_switch_wall, "last_switch_s": self.last_switch_s,
                "last_refusal": None if self.last_refusal is None else self.last_refusal.value,
                "last_refusal_detail": self.last_refusal_detail, "last_refused_version": self.last_refused_version,
                "refused_since_switch": self._refused_after_switch,
                "loading": None if loading is None else loading.version,
                "pending": None if ready is None else ready[0].version,
            }


def _label(v: MapVersion) -> str:
    if v.name is None and v.version is None:
        return v.map_id or str(v.path)
    return f"{v.name}@{v.version}"
