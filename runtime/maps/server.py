"""The map service on a Zenoh session: one queryable over `litevloc/maps/**` answering from a
`MapStore`, and a publication per map announcing each new latest version (`keys` lists the key
space).

Reads (index, latest, versions, manifest, chunks) are answered on Zenoh's callback thread: each
is one small file read. A push is uploaded chunk by chunk into `<store>/.uploads/<id>/` (each
chunk checked against the sha256 the client declared up front) and committed by one query;
the commit runs on a worker thread because building the candidate takes seconds to minutes:
the `PushGate` the service was given builds it (map update / map merge) and compares it with
the current version (the held-out check), and only an accepted candidate becomes a version.
The service never deletes a version and has no handler that writes one from a put.
"""

from __future__ import annotations

import contextlib
import hashlib
import logging
import shutil
import threading
import time
import uuid
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

from litevloc.runtime.maps import keys
from litevloc.runtime.maps.errors import MapErrorKind, MapServiceError
from litevloc.runtime.maps.store import MapStore, MapVersionInfo, check_name, file_lock
from litevloc.runtime.maps.transfer import Chunk, TransferManifest, check_files, read_chunk, write_chunk

log = logging.getLogger(__name__)
PUSH_KINDS = ("map", "recording")
UPLOAD_TTL_S = 3600.0


@dataclass(frozen=True)
class PushVerdict:
    """A gate's decision on a pushed session: `accept` it as the new latest (the candidate map was
    written to the gate's `out` folder), `reason` one line for the robot, `details` the figures
    (JSON-able) behind it."""

    accept: bool
    reason: str
    details: dict[str, Any] = field(default_factory=dict)


class PushGate(Protocol):
    """Builds a candidate from a push and judges it against the current version.

    `current`: folder of the current latest (None for a map's first version); `upload`: the
    pushed files (a map folder for kind "map", else one recording file inside it); `out`: where
    to write the candidate map folder (absent before the call)."""

    def __call__(self, name: str, current: Path | None, upload: Path, kind: str, out: Path) -> PushVerdict: ...


@dataclass
class _Upload:
    name: str
    kind: str
    manifest: TransferManifest
    folder: Path
    received: set[int] = field(default_factory=set)
    t_begin: float = field(default_factory=time.monotonic)


class MapServer:
    """Serves `store` on `session`; `gate` decides pushes (None: every push is refused)."""

    def __init__(self, session: Any, store: MapStore, gate: PushGate | None = None,
                 max_push_bytes: int = 4 << 30, on_event: Callable[[str, dict[str, Any]], None] | None = None) -> None:
        self.session, self.store, self.gate = session, store, gate
        self.max_push_bytes = int(max_push_bytes)
        self.on_event = on_event
        self._uploads: dict[str, _Upload] = {}
        self._lock = threading.Lock()
        self._publishers: dict[str, Any] = {}
        self._manifests: dict[tuple[str, str], TransferManifest] = {}  # versions never change: cached for good
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="map-push")
        self.counts = {"queries": 0, "chunks_served": 0, "bytes_served": 0, "errors": 0, "pushes_accepted": 0,
                       "pushes_refused": 0}
        self._owner = contextlib.ExitStack()
        if not self._owner.enter_context(file_lock(store.root / ".service.lock", wait=False)):
            self._owner.close()
            raise MapServiceError(MapErrorKind.CONFLICT, f"another map service is serving {store.root}")
        shutil.rmtree(store.root / ".uploads", ignore_errors=True)  # uploads cut by a restart: the robot pushes again
        self._queryables = [session.declare_queryable(k, self._on_query, complete=True)
                            for k in (*keys.READ_KEYS, *keys.PUSH_KEYS, *keys.ROLLBACK_KEYS)]

    def close(self) -> None:
        for q in self._queryables:
            q.undeclare()
        self._pool.shutdown(wait=True, cancel_futures=True)
        for pub in self._publishers.values():
            pub.undeclare()
        self._publishers.clear()
        self._owner.close()

    def __enter__(self) -> MapServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ announcements
    def announce(self, info: MapVersionInfo) -> None:
        """Publish `info` on `litevloc/maps/<name>/announce` (a new latest, or a rollback)."""
        with self._lock:
            pub = self._publishers.get(info.name)
            if pub is None:
                import zenoh

                pub = self.session.declare_publisher(keys.announce_key(info.name),
                                                     congestion_control=zenoh.CongestionControl.BLOCK)
                self._publishers[info.name] = pub
        pub.put(keys.dumps(info.to_json()), encoding="application/json")
        self._event("announce", info.to_json())

    def publish(self, name: str, folder: Path, parent: str | None = None) -> MapVersionInfo:
        """Add `folder` as the latest version of `name` and announce it (the operator's path)."""
        before = self._latest_or_none(name)
        info = self.store.add_version(name, folder, parent=parent)
        if before is None or before.version != info.version:
            self.announce(info)
        return info

    def rollback(self, name: str, version: str) -> MapVersionInfo:
        info = self.store.rollback(name, version)
        self.announce(info)
        return info

    def _latest_or_none(self, name: str) -> MapVersionInfo | None:
        try:
            return self.store.latest(name)
        except MapServiceError as exc:
            if exc.kind is MapErrorKind.NOT_FOUND:
                return None
            raise

    def _event(self, what: str, data: dict[str, Any]) -> None:
        if self.on_event is not None:
            self.on_event(what, data)

    # ------------------------------------------------------------------ queries
    def _on_query(self, query: Any) -> None:
        key = str(query.key_expr)
        self.counts["queries"] += 1
        parts = key.split("/")[2:]  # after litevloc/maps
        try:
            payload = query.payload.to_bytes() if query.payload is not None else b""
            if parts[:2] and parts[-1] == "commit" and len(parts) == 4 and parts[1] == "push":
                self._pool.submit(self._commit_and_reply, query, parts[0], parts[2])
                return  # replied and dropped by the worker
            out = self._answer(parts, payload)
            if isinstance(out, bytes):
                query.reply(key, out)
                self.counts["chunks_served"] += 1
                self.counts["bytes_served"] += len(out)
            else:
                query.reply(key, keys.dumps(out), encoding="application/json")
        except MapServiceError as exc:
            self.counts["errors"] += 1
            query.reply_err(keys.error_payload(exc))
        except Exception as exc:  # a bug must not take down the service: report it to the asker and the log
            log.exception("map service: query %s failed", key)
            self.counts["errors"] += 1
            query.reply_err(keys.error_payload(MapServiceError(MapErrorKind.BAD_REQUEST, f"{key}: {exc}")))
        query.drop()

    def _answer(self, parts: list[str], payload: bytes) -> Any:
        if parts == ["_index"]:
            return {"maps": [{"name": n, "latest": self.store.latest(n).to_json()} for n in self.store.names()]}
        if not parts:
            raise MapServiceError(MapErrorKind.BAD_REQUEST, "empty map key")
        name, rest = check_name(parts[0]), parts[1:]
        if rest == ["latest"]:
            return self.store.latest(name).to_json()
        if rest == ["versions"]:
            return {"latest": self.store.latest(name).version, "versions": [v.to_json() for v in
                    self.store.versions(name)], "history": self.store.history(name)}
        if len(rest) == 3 and rest[0] == "v" and rest[2] == "manifest":
            version = self.store.resolve(name, rest[1])
            return {"info": self.store.info(name, version).to_json(),
                    "transfer": self.store.manifest(name, version).to_json()}
        if len(rest) == 4 and rest[0] == "v" and rest[2] == "chunk":
            return self._chunk(name, rest[1], rest[3])
        if rest == ["push", "begin"]:
            return self._begin(name, payload)
        if len(rest) == 4 and rest[0] == "push" and rest[2] == "chunk":
            return self._receive(name, rest[1], rest[3], payload)
        if rest == ["rollback"]:
            d = keys.loads(payload, "rollback request")
            if not isinstance(d, dict) or not isinstance(d.get("version"), str):
                raise MapServiceError(MapErrorKind.BAD_REQUEST, 'rollback needs {"version": "..."}')
            return self.rollback(name, d["version"]).to_json()
        raise MapServiceError(MapErrorKind.BAD_REQUEST, f"unknown map service key {'/'.join(parts)!r}")

    def _manifest(self, name: str, version: str) -> TransferManifest:
        m = self._manifests.get((name, version))
        if m is None:
            m = self.store.manifest(name, self.store.resolve(name, version))
            with self._lock:
                self._manifests[(name, m.content_hash)] = m
        return m

    def _chunk(self, name: str, version: str, index: str) -> bytes:
        m = self._manifest(name, version)
        i = _index(index, len(m.chunks))
        return read_chunk(self.store.map_path(name, m.content_hash), m.chunks[i])

    # ------------------------------------------------------------------ pushes
    def _begin(self, name: str, payload: bytes) -> dict[str, Any]:
        d = keys.loads(payload, "push request")
        kind = d.get("kind") if isinstance(d, dict) else None
        if kind not in PUSH_KINDS:
            raise MapServiceError(MapErrorKind.BAD_REQUEST, f"push kind must be one of {PUSH_KINDS}, got {kind!r}")
        m = TransferManifest.from_json(d.get("transfer"))
        if m.size_bytes > self.max_push_bytes:
            raise MapServiceError(MapErrorKind.REFUSED, f"push of {m.size_bytes} bytes exceeds this service's "
                                  f"limit of {self.max_push_bytes}")
        if kind == "recording" and len(m.files) != 1:
            raise MapServiceError(MapErrorKind.BAD_REQUEST, "a pushed recording is one file")
        self._drop_stale_uploads()
        upload = uuid.uuid4().hex
        folder = self.store.root / ".uploads" / upload
        folder.mkdir(parents=True)
        for rel, e in m.files.items():
            if int(e["bytes"]) == 0:
                write_chunk(folder, _empty_chunk(rel), b"")
        with self._lock:
            self._uploads[upload] = _Upload(name, str(kind), m, folder)
        return {"upload": upload, "chunks": len(m.chunks)}

    def _drop_stale_uploads(self) -> None:
        """Forget pushes not committed within `UPLOAD_TTL_S` (a robot that lost its link pushes again)."""
        now = time.monotonic()
        with self._lock:
            stale = [k for k, u in self._uploads.items() if now - u.t_begin > UPLOAD_TTL_S]
            for k in stale:
                shutil.rmtree(self._uploads.pop(k).folder, ignore_errors=True)

    def _upload(self, name: str, upload: str) -> _Upload:
        with self._lock:
            up = self._uploads.get(upload)
        if up is None or up.name != name:
            raise MapServiceError(MapErrorKind.NOT_FOUND, f"no push {upload!r} under way for map {name!r}")
        return up

    def _receive(self, name: str, upload: str, index: str, payload: bytes) -> dict[str, Any]:
        up = self._upload(name, upload)
        i = _index(index, len(up.manifest.chunks))
        c = up.manifest.chunks[i]
        if len(payload) != c.size or hashlib.sha256(payload).hexdigest() != c.sha256:
            raise MapServiceError(MapErrorKind.CHECKSUM, f"push chunk {i}: bytes do not match its sha256")
        write_chunk(up.folder, c, payload)
        up.received.add(i)
        return {"ok": True}

    def _commit_and_reply(self, query: Any, name: str, upload: str) -> None:
        key = str(query.key_expr)
        try:
            query.reply(key, keys.dumps(self._commit(check_name(name), upload)), encoding="application/json")
        except MapServiceError as exc:
            query.reply_err(keys.error_payload(exc))
        except Exception as exc:
            log.exception("map service: push commit %s failed", key)
            query.reply_err(keys.error_payload(MapServiceError(MapErrorKind.REFUSED, f"candidate build failed: "
                                                                                     f"{type(exc).__name__}: {exc}")))
        finally:
            query.drop()

    def _commit(self, name: str, upload: str) -> dict[str, Any]:
        up = self._upload(name, upload)
        try:
            missing = len(up.manifest.chunks) - len(up.received)
            if missing:
                raise MapServiceError(MapErrorKind.BAD_REQUEST, f"push {upload}: {missing} chunks not received")
            check_files(up.folder, up.manifest)
            current = self._latest_or_none(name)
            if self.gate is None:
                verdict = PushVerdict(False, "this map service accepts no pushes (started without a held-out "
                                             "check: map serve --held-out REC)")
            else:
                src = up.folder if up.kind == "map" else up.folder / next(iter(up.manifest.files))
                cur = self.store.map_path(name, current.version) if current else None
                verdict = self.gate(name, cur, src, up.kind, up.folder.with_name(upload + ".candidate"))
            out: dict[str, Any] = {"published": False, "reason": verdict.reason, "details": verdict.details,
                                   "info": None}
            if verdict.accept:
                info = self.publish(name, up.folder.with_name(upload + ".candidate"),
                                    parent=current.version if current else None)
                out.update(published=True, info=info.to_json())
                self.counts["pushes_accepted"] += 1
            else:
                self.counts["pushes_refused"] += 1
            self._event("push", {"name": name, **out})
            return out
        finally:
            with self._lock:
                self._uploads.pop(upload, None)
            shutil.rmtree(up.folder, ignore_errors=True)
            shutil.rmtree(up.folder.with_name(upload + ".candidate"), ignore_errors=True)


def _index(text: str, n: int) -> int:
    if not text.isdigit() or not 0 <= int(text) < n:
        raise MapServiceError(MapErrorKind.BAD_REQUEST, f"chunk index {text!r} out of range (0..{n - 1})")
    return int(text)


def _empty_chunk(rel: str) -> Chunk:
    return Chunk(rel, 0, 0, "")
