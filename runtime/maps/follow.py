"""A robot that follows its map: each announced new version of map NAME is fetched (through the
local cache) on a worker thread of its own and handed to `on_fetched`, the onboard service's
`App.request_map_switch`, which loads, checks and switches to it between two VLoc results.

Announcements arrive on Zenoh's thread; fetching there would stall every other subscriber, so the
callback only records the newest announced version and wakes the worker. Versions announced while
a fetch runs collapse into the newest; a failed fetch is counted and logged, the map in use kept.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from litevloc.base.params.fleet import FleetParams
from litevloc.runtime.maps.app import cache_dir_of
from litevloc.runtime.maps.client import FetchedMap, fetch_map, subscribe_announcements
from litevloc.runtime.maps.errors import MapServiceError
from litevloc.runtime.maps.store import MapVersionInfo

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class FollowReport:
    """What a follower did: announcements seen, versions fetched and handed over, fetch failures."""

    name: str
    current: str
    announced: int
    fetched: int
    failed: int
    last_error: str


class MapFollower:
    """Follow `litevloc/maps/<name>/announce` on `session` and hand each new version, fetched into
    the cache, to `on_fetched(path, name, version)`. `current` is the version in use (announcements
    of it are ignored). Close with `close()` (joins the worker)."""

    def __init__(self, session: Any, name: str, current: str, params: FleetParams,
                 on_fetched: Callable[[Path, str, str], None],
                 fetch: Callable[..., FetchedMap] = fetch_map) -> None:
        self.name, self.params, self._on_fetched, self._fetch = name, params, on_fetched, fetch
        self._session = session
        self._current = current
        self._wanted: str | None = None
        self._announced = self._fetched = self._failed = 0
        self._last_error = ""
        self._cond = threading.Condition()
        self._closed = False
        self._worker = threading.Thread(target=self._run, name=f"map-follow-{name}", daemon=True)
        self._worker.start()
        self._sub = subscribe_announcements(session, name, self._on_announce)

    def _on_announce(self, info: MapVersionInfo) -> None:
        with self._cond:
            self._announced += 1
            if info.version != self._current:
                self._wanted = info.version
                self._cond.notify()

    def _run(self) -> None:
        while True:
            with self._cond:
                while self._wanted is None and not self._closed:
                    self._cond.wait()
                if self._closed:
                    return
                version, self._wanted = self._wanted, None
            assert version is not None
            try:
                got = self._fetch(self._session, self.name, version, cache_dir_of(self.params),
                                  timeout_s=self.params.query_timeout_s, retries=self.params.chunk_retries,
                                  window=self.params.fetch_window)
            except MapServiceError as exc:
                with self._cond:
                    self._failed += 1
                    self._last_error = f"{exc.kind.value}: {exc}"
                log.warning("map %r: version %s announced but not fetched (%s); keeping %s", self.name,
                            version[:12], exc, self._current[:12])
                continue
            with self._cond:
                self._fetched += 1
                self._current = got.version
            log.info("map %r: version %s fetched, switching", self.name, got.version[:12])
            self._on_fetched(got.path, got.name, got.version)

    def report(self) -> FollowReport:
        with self._cond:
            return FollowReport(self.name, self._current, self._announced, self._fetched, self._failed,
                                self._last_error)

    def close(self) -> None:
        self._sub.close()
        with self._cond:
            self._closed = True
            self._cond.notify()
        self._worker.join(timeout=10.0)
