"""The robot's side of the map service: fetch a version into a local cache, follow announcements,
list versions, push a session, ask for a rollback.

`fetch_map` keeps a local `MapStore` as its cache (`cache_dir`): a version fetched once is
there for good (versions are immutable), so a robot whose server is down starts from the
cached latest (`FetchedMap.offline`), and a named version already cached needs no network.
A transfer writes into `cache_dir/.partial/<name>/<version>/`; an interrupted one is resumed by
keeping every chunk whose bytes on disk already hash right. Each chunk is checked on arrival
and fetched again when it does not hash right (`retries` times, then `MapServiceError(CHECKSUM)`);
the assembled files and the whole map's hash are checked before the version enters the cache.
"""

from __future__ import annotations

import hashlib
import logging
import shutil
import threading
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from litevloc.runtime.maps import keys
from litevloc.runtime.maps.errors import MapErrorKind, MapServiceError
from litevloc.runtime.maps.store import VERSION_RE, MapStore, MapVersionInfo, check_name, file_lock
from litevloc.runtime.maps.transfer import (
    Chunk,
    TransferManifest,
    check_files,
    chunk_on_disk,
    file_entries,
    read_chunk,
    sha256_file,
    transfer_manifest,
    write_chunk,
)

log = logging.getLogger(__name__)
Progress = Callable[[int, int], None]  # (bytes done, bytes total)


@dataclass(frozen=True)
class FetchedMap:
    """A map version ready to load: `path` is its folder in the cache (read-only for the caller).
    `offline`: the server did not answer and this is the cached latest; `chunks_fetched` /
    `chunks_resumed` / `chunks_refetched`: what this call moved (0 when served from the cache)."""

    name: str
    version: str
    path: Path
    offline: bool = False
    from_cache: bool = False
    bytes_fetched: int = 0
    chunks_fetched: int = 0
    chunks_resumed: int = 0
    chunks_refetched: int = 0


def ask(session: Any, key: str, payload: bytes | None = None, timeout_s: float = 5.0) -> bytes:
    """One query, one answer: the first reply's bytes; an error reply raises its `MapServiceError`;
    no reply at all (no route, refused by access control, timed out) raises UNREACHABLE."""
    return answer(session.get(key, payload=payload, timeout=timeout_s), key, timeout_s)


def answer(replies: Any, key: str, timeout_s: float) -> bytes:
    """The bytes of the first reply of a pending `session.get` (see `ask`)."""
    for reply in replies:
        if reply.ok is not None:
            return bytes(reply.ok.payload.to_bytes())
        raise keys.error_from_payload(reply.err.payload.to_bytes(), key)
    raise MapServiceError(MapErrorKind.UNREACHABLE, f"no map service answered {key} within {timeout_s:g} s "
                          "(not reachable, not running, or this robot is not allowed to read)")


def ask_json(session: Any, key: str, payload: Any = None, timeout_s: float = 5.0) -> Any:
    data = None if payload is None else keys.dumps(payload)
    return keys.loads(ask(session, key, data, timeout_s), key)


def latest_version(session: Any, name: str, timeout_s: float = 5.0) -> MapVersionInfo:
    return MapVersionInfo.from_json(ask_json(session, keys.latest_key(check_name(name)), timeout_s=timeout_s))


def list_versions(session: Any, name: str, timeout_s: float = 5.0) -> dict[str, Any]:
    """`{"latest": version, "versions": [MapVersionInfo], "history": [...]}` of `name`."""
    d = ask_json(session, keys.versions_key(check_name(name)), timeout_s=timeout_s)
    if not isinstance(d, dict) or not isinstance(d.get("versions"), list):
        raise MapServiceError(MapErrorKind.BAD_REPLY, f"versions of {name!r}: malformed reply")
    return {"latest": d.get("latest"), "versions": [MapVersionInfo.from_json(v) for v in d["versions"]],
            "history": d.get("history", [])}


def request_rollback(session: Any, name: str, version: str, timeout_s: float = 5.0) -> MapVersionInfo:
    """Ask the service to make `version` (hash or unique prefix) the latest of `name` again."""
    return MapVersionInfo.from_json(ask_json(session, keys.rollback_key(check_name(name)), {"version": version},
                                             timeout_s=timeout_s))


def _cached(cache: MapStore, name: str, version: str | None) -> MapVersionInfo | None:
    try:
        return cache.latest(name) if version is None else cache.info(name, cache.resolve(name, version))
    except MapServiceError as exc:
        if exc.kind in (MapErrorKind.NOT_FOUND, MapErrorKind.BAD_REQUEST):
            return None
        raise


def cached_map(cache_dir: str | Path, name: str, version: str | None) -> FetchedMap | None:
    """The cached latest (or named) version of `name` as an offline `FetchedMap`, None if not cached."""
    cache = MapStore(cache_dir)
    hit = _cached(cache, check_name(name), version)
    if hit is None:
        return None
    return FetchedMap(name, hit.version, cache.map_path(name, hit.version), offline=True, from_cache=True)


def fetch_map(session: Any, name: str, version: str | None, cache_dir: str | Path, progress: Progress | None = None,
              *, timeout_s: float = 5.0, retries: int = 3, allow_offline: bool = True, window: int = 4) -> FetchedMap:
    """Fetch version `version` (hash, unique prefix, or None: the latest) of map `name` into
    `cache_dir` and return its local folder. See the module docstring for resume, checks and the
    offline case (`allow_offline=False` raises UNREACHABLE instead). `progress(done, total)` in
    bytes; `window`: chunk queries in flight."""
    check_name(name)
    cache = MapStore(cache_dir)
    if version is not None and VERSION_RE.match(version) and (hit := _cached(cache, name, version)):
        return FetchedMap(name, hit.version, cache.map_path(name, hit.version), from_cache=True)
    try:
        if version is None:
            info = latest_version(session, name, timeout_s)
            man = ask_json(session, keys.manifest_key(name, info.version), timeout_s=timeout_s)
        else:
            man = ask_json(session, keys.manifest_key(name, version), timeout_s=timeout_s)
            info = MapVersionInfo.from_json(man.get("info") if isinstance(man, dict) else None)
    except MapServiceError as exc:
        hit = _cached(cache, name, version) if exc.kind is MapErrorKind.UNREACHABLE and allow_offline else None
        if hit is None:
            raise
        log.warning("map service unreachable: using the cached version %s of map %r (%s)", hit.version[:12], name,
                    "latest cached" if version is None else "as asked")
        return FetchedMap(name, hit.version, cache.map_path(name, hit.version), offline=True, from_cache=True)
    if info.name != name:
        raise MapServiceError(MapErrorKind.BAD_REPLY, f"asked for map {name!r}, the service answered {info.name!r}")
    if _cached(cache, name, info.version):
        if version is None:
            cache.set_latest(name, info.version, "fetch")
        return FetchedMap(name, info.version, cache.map_path(name, info.version), from_cache=True)
    m = TransferManifest.from_json(man.get("transfer") if isinstance(man, dict) else None)
    if m.content_hash != info.version:
        raise MapServiceError(MapErrorKind.BAD_REPLY, f"map {name!r}: manifest of {m.content_hash[:12]} served for "
                              f"version {info.version[:12]}")
    partial = cache.root / ".partial" / name / info.version
    with file_lock(partial.with_name(info.version + ".lock")):  # robots sharing a cache fetch a version once
        if not _cached(cache, name, info.version):
            stats = _transfer(session, name, info.version, m, partial, progress, timeout_s, retries, max(1, window))
            try:
                check_files(partial, m)
            except MapServiceError:
                shutil.rmtree(partial, ignore_errors=True)  # every chunk hashed right, the files not: start over
                raise
            cache.add_version(name, partial, move=True, expect=info, make_latest=False)
        else:
            stats = dict.fromkeys(("bytes_fetched", "chunks_fetched", "chunks_resumed", "chunks_refetched"), 0)
    if version is None or _cached(cache, name, None) is None:
        cache.set_latest(name, info.version, "fetch")
    return FetchedMap(name, info.version, cache.map_path(name, info.version), bytes_fetched=stats["bytes_fetched"],
                      chunks_fetched=stats["chunks_fetched"], chunks_resumed=stats["chunks_resumed"],
                      chunks_refetched=stats["chunks_refetched"])


def _transfer(session: Any, name: str, version: str, m: TransferManifest, partial: Path,
              progress: Progress | None, timeout_s: float, retries: int, window: int) -> dict[str, int]:
    """Fetch the chunks `partial` lacks, `window` queries in flight (a round trip per chunk would
    bound a fetch over Wi-Fi by latency, not bandwidth); each checked before it is written."""
    partial.mkdir(parents=True, exist_ok=True)
    for rel, e in m.files.items():
        if int(e["bytes"]) == 0:
            write_chunk(partial, Chunk(rel, 0, 0, ""), b"")
    stats = {"bytes_fetched": 0, "chunks_fetched": 0, "chunks_resumed": 0, "chunks_refetched": 0}
    done, total = 0, m.size_bytes
    needed: deque[int] = deque()
    for i, c in enumerate(m.chunks):
        if chunk_on_disk(partial, c):
            stats["chunks_resumed"] += 1
            done += c.size
        else:
            needed.append(i)
    if progress is not None and done:
        progress(done, total)
    pending: deque[tuple[int, Any]] = deque()
    while needed or pending:
        while needed and len(pending) < window:
            i = needed.popleft()
            pending.append((i, session.get(keys.chunk_key(name, version, i), timeout=timeout_s)))
        i, replies = pending.popleft()
        c = m.chunks[i]
        data = answer(replies, keys.chunk_key(name, version, i), timeout_s)
        for attempt in range(retries + 1):
            stats["bytes_fetched"] += len(data)
            if len(data) == c.size and hashlib.sha256(data).hexdigest() == c.sha256:
                write_chunk(partial, c, data)
                break
            stats["chunks_refetched"] += 1
            log.warning("map %r %s: chunk %d does not match its sha256 (try %d of %d)", name, version[:12], i,
                        attempt + 1, retries + 1)
            if attempt < retries:
                data = ask(session, keys.chunk_key(name, version, i), timeout_s=timeout_s)
        else:
            raise MapServiceError(MapErrorKind.CHECKSUM, f"map {name!r} version {version[:12]}: chunk {i} "
                                  f"({c.path} @ {c.offset}) failed its sha256 {retries + 1} times; refused")
        stats["chunks_fetched"] += 1
        done += c.size
        if progress is not None:
            progress(done, total)
    return stats


class AnnouncementSubscription:
    """Calls `callback(MapVersionInfo)` for each announcement of map `name`; malformed ones and
    callback failures are counted (`rejected`, `callback_errors`) and logged, never raised into
    Zenoh's thread. `close()` undeclares it."""

    def __init__(self, session: Any, name: str, callback: Callable[[MapVersionInfo], None]) -> None:
        self.name, self.callback = check_name(name), callback
        self.received = self.rejected = self.callback_errors = 0
        self._lock = threading.Lock()
        self._sub = session.declare_subscriber(keys.announce_key(name), self._on_sample)

    def _on_sample(self, sample: Any) -> None:
        try:
            info = MapVersionInfo.from_json(keys.loads(sample.payload.to_bytes(), "announcement"))
            if info.name != self.name:
                raise MapServiceError(MapErrorKind.BAD_REPLY, f"announcement names map {info.name!r}")
        except MapServiceError as exc:
            with self._lock:
                self.rejected += 1
            log.warning("map %r: announcement ignored: %s", self.name, exc)
            return
        with self._lock:
            self.received += 1
        try:
            self.callback(info)
        except Exception:
            with self._lock:
                self.callback_errors += 1
            log.exception("map %r: announcement callback failed", self.name)

    def close(self) -> None:
        self._sub.undeclare()

    def __enter__(self) -> AnnouncementSubscription:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def subscribe_announcements(session: Any, name: str, callback: Callable[[MapVersionInfo], None]
                            ) -> AnnouncementSubscription:
    """Follow `litevloc/maps/<name>/announce`: `callback` gets each new latest version (or rollback)."""
    return AnnouncementSubscription(session, name, callback)


@dataclass(frozen=True)
class PushResult:
    """The service's answer to a push: `published` (then `info` is the new latest) or the one-line
    `reason` it refused; `details` the figures of its held-out check."""

    published: bool
    reason: str
    info: MapVersionInfo | None
    details: dict[str, Any]


def push_map(session: Any, name: str, src: str | Path, *, chunk_bytes: int = 1 << 20, timeout_s: float = 5.0,
             retries: int = 3, commit_timeout_s: float = 900.0, progress: Progress | None = None) -> PushResult:
    """Upload a session map folder (kind "map") or a recording file (kind "recording") to map
    `name` and wait for the service's verdict (it builds and checks a candidate, minutes)."""
    check_name(name)
    src = Path(src)
    if src.is_dir() and (src / "manifest.json").is_file():
        kind, folder, m = "map", src, transfer_manifest(src, chunk_bytes)
    elif src.is_file():
        entries = {src.name: {"sha256": sha256_file(src), "bytes": src.stat().st_size}}
        kind, folder, m = "recording", src.parent, transfer_manifest(src.parent, chunk_bytes, entries)
    else:
        raise MapServiceError(MapErrorKind.BAD_REQUEST, f"{src}: push a map folder or a recording file")
    if kind == "map":
        file_entries(src)  # refuses symlinks and odd files before anything is sent
    begin = ask_json(session, keys.push_begin_key(name), {"kind": kind, "transfer": m.to_json()}, timeout_s)
    upload = str(begin.get("upload", "")) if isinstance(begin, dict) else ""
    if not upload.isalnum():
        raise MapServiceError(MapErrorKind.BAD_REPLY, f"push of {src}: malformed begin reply")
    done = 0
    for i, c in enumerate(m.chunks):
        data = read_chunk(folder, c)
        for attempt in range(retries + 1):
            try:
                ask(session, keys.push_chunk_key(name, upload, i), data, timeout_s)
                break
            except MapServiceError as exc:
                if exc.kind is not MapErrorKind.CHECKSUM or attempt == retries:
                    raise
        done += c.size
        if progress is not None:
            progress(done, m.size_bytes)
    d = ask_json(session, keys.push_commit_key(name, upload), timeout_s=commit_timeout_s)
    if not isinstance(d, dict) or not isinstance(d.get("published"), bool):
        raise MapServiceError(MapErrorKind.BAD_REPLY, f"push of {src}: malformed verdict")
    info = MapVersionInfo.from_json(d["info"]) if d.get("published") else None
    return PushResult(bool(d["published"]), str(d.get("reason", "")), info, dict(d.get("details") or {}))


def clear_partial(cache_dir: str | Path, name: str) -> None:
    """Drop interrupted transfers of `name` from the cache (the next fetch starts over)."""
    shutil.rmtree(Path(cache_dir) / ".partial" / check_name(name), ignore_errors=True)
