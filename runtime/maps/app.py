"""Entry points the command line calls: run the map service until stopped, open a robot's
session to it, resolve `zenoh:NAME[@VERSION]` to a fetched local map folder."""

from __future__ import annotations

import dataclasses
import logging
import os
import shutil
import signal
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Literal

from litevloc.base.params.fleet import FleetParams
from litevloc.config.schema import ZenohConfig
from litevloc.runtime.maps.client import FetchedMap, Progress, cached_map, fetch_map
from litevloc.runtime.maps.errors import MapErrorKind, MapServiceError
from litevloc.runtime.maps.server import MapServer, PushGate
from litevloc.runtime.maps.store import MapStore, check_name
from litevloc.runtime.transport.bus import BusError, open_session

log = logging.getLogger(__name__)
URI_SCHEME = "zenoh:"
ServiceMode = Literal["router", "peer", "client"]


def cache_dir_of(params: FleetParams) -> Path:
    """`fleet.cache_dir`, else $LITEVLOC_MAP_CACHE, else ~/.cache/litevloc/maps."""
    return Path(params.cache_dir or os.environ.get("LITEVLOC_MAP_CACHE") or Path.home() / ".cache/litevloc/maps")


def parse_map_uri(text: str) -> tuple[str, str | None] | None:
    """`zenoh:NAME[@VERSION]` -> (NAME, VERSION or None); None when `text` is not such a URI."""
    if not text.startswith(URI_SCHEME):
        return None
    name, _, version = text[len(URI_SCHEME):].partition("@")
    return check_name(name), (version or None)


def robot_zenoh(cfg: ZenohConfig) -> ZenohConfig:
    """The robot's session for talking to the map service: its configured one, listening nowhere
    (a fetch before the service starts must not take the service's listen port)."""
    return dataclasses.replace(cfg, listen=())


@contextmanager
def robot_session(cfg: ZenohConfig) -> Iterator[Any]:
    session = open_session(robot_zenoh(cfg))
    try:
        yield session
    finally:
        session.close()


def resolve_map(text: str, zcfg: ZenohConfig, params: FleetParams, progress: Progress | None = None
                ) -> FetchedMap | None:
    """Fetch the map a `zenoh:NAME[@VERSION]` names (or take it from the cache when the service is
    unreachable); None when `text` is a plain folder path."""
    parsed = parse_map_uri(text)
    if parsed is None:
        return None
    name, version = parsed
    cfg = dataclasses.replace(robot_zenoh(zcfg), require_connect=False)  # offline: start from the cache
    try:
        session = open_session(cfg)
    except BusError as exc:  # a client whose router is down cannot open a session at all
        got = cached_map(cache_dir_of(params), name, version)
        if got is None:
            raise MapServiceError(MapErrorKind.UNREACHABLE, f"map {name!r}: {exc}; and no cached version") from exc
    else:
        try:
            got = fetch_map(session, name, version, cache_dir_of(params), progress, timeout_s=params.query_timeout_s,
                            retries=params.chunk_retries, window=params.fetch_window)
        finally:
            session.close()
    log.info("map %s version %s at %s%s", name, got.version[:12], got.path,
             " (map service unreachable: the cached version)" if got.offline else "")
    return got


def fetch_to_folder(zcfg: ZenohConfig, params: FleetParams, name: str, version: str | None, output: Path
                    ) -> FetchedMap:
    """Fetch (through the cache) and copy the version into `output`, replaced atomically
    (a sibling `.partial` folder renamed into place)."""
    with robot_session(zcfg) as session:
        got = fetch_map(session, name, version, cache_dir_of(params), timeout_s=params.query_timeout_s,
                        retries=params.chunk_retries, window=params.fetch_window)
    tmp = output.with_name(output.name + ".partial")
    shutil.rmtree(tmp, ignore_errors=True)
    shutil.copytree(got.path, tmp)
    if output.exists():
        shutil.rmtree(output)
    tmp.rename(output)
    return got


def serve_maps(root: Path, zcfg: ZenohConfig, params: FleetParams, mode: ServiceMode = "router",
               gate: PushGate | None = None, add: dict[str, Path] | None = None,
               stop: threading.Event | None = None, on_ready: Callable[[MapServer], None] | None = None
               ) -> dict[str, Any]:
    """Run the map service on `root` until `stop` is set (or SIGINT / SIGTERM): `add` publishes map folders
    first (name -> folder). Returns the service's counters."""
    if mode == "client" and not zcfg.connect:
        raise MapServiceError(MapErrorKind.BAD_REQUEST, "map serve in client mode needs --connect ROUTER")
    store = MapStore(root, chunk_bytes=params.chunk_bytes)
    session = open_session(zcfg, mode=mode)
    stop = stop or threading.Event()
    try:
        with MapServer(session, store, gate, params.max_push_bytes) as server:
            for name, folder in (add or {}).items():
                info = server.publish(name, folder)
                log.info("map %s: version %s (%d bytes) is the latest", name, info.version[:12], info.size_bytes)
            for name in store.names():
                log.info("serving map %s: %d versions, latest %s", name, len(store.versions(name)),
                         store.latest(name).version[:12])
            if threading.current_thread() is threading.main_thread():  # systemd stops a service with SIGTERM
                signal.signal(signal.SIGTERM, lambda *_: stop.set())
            if on_ready is not None:
                on_ready(server)
            try:
                while not stop.wait(0.5):
                    pass
            except KeyboardInterrupt:
                pass
            return dict(server.counts)
    finally:
        session.close()
