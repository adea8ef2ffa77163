"""A versioned map store on disk: every version immutable and addressed by its content hash.

Layout under the store's root (one folder per map name):

```
<name>/versions/<version>/map/...        the map folder's files, exactly as `map build` wrote them
<name>/versions/<version>/version.json   MapVersionInfo + the transfer manifest (files, chunks)
<name>/latest.json                       {"version": ...}: the version robots get by default
<name>/history.jsonl                     one line per move of `latest` (publish, rollback), append-only
<name>/.staging/<pid>-<id>/              versions being written; never listed; removed once their writer is gone
```

`version` is the sha256 (hex) of the canonical file list (`content_hash`): the same files give
the same version, so publishing twice is a no-op, and a version folder is never rewritten.
A version is written into `.staging/`, every file and folder fsynced, then renamed into
`versions/` in one `rename`: a process killed at any point leaves either no version or a
complete one, and a restart lists exactly the complete ones. `latest.json` is replaced the
same way (temp file, fsync, `os.replace`). Nothing here deletes a version: `rollback` moves
`latest` to an older one and records the move.
"""

from __future__ import annotations

import fcntl
import json
import os
import re
import shutil
import time
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from litevloc.runtime.maps.errors import MapErrorKind, MapServiceError
from litevloc.runtime.maps.transfer import TransferManifest, content_hash, file_entries, transfer_manifest

NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$")
VERSION_RE = re.compile(r"^[0-9a-f]{64}$")
MIN_PREFIX = 8


def check_name(name: str) -> str:
    """`name` if it is a map name (letters, digits, `_ . -`, starting with a letter or digit, <= 64)."""
    if not NAME_RE.match(name):
        raise MapServiceError(MapErrorKind.BAD_REQUEST,
                              f"map name {name!r}: use letters, digits, '_', '.', '-' (starting with a letter or "
                              "digit, at most 64)")
    return name


@dataclass(frozen=True)
class MapVersionInfo:
    """One version of a map: `version` the content hash (64 hex), `parent` the version that was
    latest when it was published (None for the first), `size_bytes` all its files, `created_ns`
    wall-clock time of publication (ns since the epoch)."""

    name: str
    version: str
    parent: str | None
    size_bytes: int
    created_ns: int

    def to_json(self) -> dict[str, Any]:
        return {"name": self.name, "version": self.version, "parent": self.parent, "size_bytes": self.size_bytes,
                "created_ns": self.created_ns}

    @classmethod
    def from_json(cls, d: Any) -> MapVersionInfo:
        """Parse and check a JSON object (from a peer: every field typed and in range)."""
        if not isinstance(d, dict):
            raise MapServiceError(MapErrorKind.BAD_REPLY, "map version info must be a JSON object")
        name, version, parent = d.get("name"), d.get("version"), d.get("parent")
        size, created = d.get("size_bytes"), d.get("created_ns")
        ok = (isinstance(name, str) and NAME_RE.match(name) and isinstance(version, str) and VERSION_RE.match(version)
              and (parent is None or (isinstance(parent, str) and VERSION_RE.match(parent)))
              and isinstance(size, int) and size >= 0 and isinstance(created, int) and created >= 0)
        if not ok:
            raise MapServiceError(MapErrorKind.BAD_REPLY, f"malformed map version info: {str(d)[:200]}")
        return cls(str(name), str(version), parent, int(size), int(created))  # type: ignore[arg-type]


def check_map_folder(src: Path, entries: dict[str, dict[str, Any]]) -> None:
    """`src` is a map as `map build` writes it: its manifest reads, lists every other file, and each
    listed file has the size and sha256 the manifest gives; else `MapServiceError(BAD_REQUEST)`."""
    from litevloc.pipelines.topomap.io import MANIFEST, MapFormatError, read_manifest

    try:
        listed = read_manifest(src)["files"]
    except MapFormatError as exc:
        raise MapServiceError(MapErrorKind.BAD_REQUEST, f"not a map folder: {exc}") from exc
    others = {k: v for k, v in entries.items() if k != MANIFEST}
    if set(others) != set(listed):
        extra, missing = sorted(set(others) - set(listed)), sorted(set(listed) - set(others))
        raise MapServiceError(MapErrorKind.BAD_REQUEST, f"map {src}: files not in its manifest {extra[:3]}, "
                              f"listed but missing {missing[:3]}")
    for rel, e in others.items():
        le = listed[rel]
        if not isinstance(le, dict) or le.get("sha256") != e["sha256"] or le.get("bytes") != e["bytes"]:
            raise MapServiceError(MapErrorKind.BAD_REQUEST, f"map {src}: {rel} does not match its manifest entry")


def _fsync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _fsync_tree(root: Path) -> None:
    """fsync every file, then every folder bottom-up, so a rename after it publishes durable bytes."""
    for dirpath, _dirs, files in os.walk(root, topdown=False):
        for f in files:
            fd = os.open(Path(dirpath) / f, os.O_RDONLY)
            try:
                os.fsync(fd)
            finally:
                os.close(fd)
        _fsync_dir(Path(dirpath))


def _writer_alive(staging_name: str) -> bool:
    """Whether the process that named a staging folder `<pid>-<id>` still runs (other processes,
    robots sharing one cache, may be writing their own versions right now)."""
    pid = staging_name.partition("-")[0]
    if not pid.isdigit():
        return False
    try:
        os.kill(int(pid), 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


@contextmanager
def file_lock(path: Path, wait: bool = True) -> Iterator[bool]:
    """An exclusive `flock` on `path` (created) while the block runs; yields False at once instead
    of waiting when `wait` is off and another process holds it."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "a+b") as f:
        try:
            fcntl.flock(f, fcntl.LOCK_EX | (0 if wait else fcntl.LOCK_NB))
        except BlockingIOError:
            yield False
            return
        try:
            yield True
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)


def write_json_atomic(path: Path, obj: Any) -> None:
    """Replace `path` by `obj` as JSON: temp file in the same folder, fsync, `os.replace`, fsync folder."""
    tmp = path.with_name(f".{path.name}.{uuid.uuid4().hex}.tmp")
    with open(tmp, "w", encoding="utf-8") as f:
        json.dump(obj, f, sort_keys=True)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)
    _fsync_dir(path.parent)


class MapStore:
    """Versions of named maps under `root` (created if missing). Thread-safe for one writer
    process: concurrent publishes of one map serialise on the rename and `latest.json`."""

    def __init__(self, root: str | Path, chunk_bytes: int = 1 << 20) -> None:
        self.root = Path(root)
        self.chunk_bytes = int(chunk_bytes)
        if self.chunk_bytes < 1024:
            raise ValueError("chunk_bytes must be >= 1024")
        self.root.mkdir(parents=True, exist_ok=True)
        for staging in self.root.glob("*/.staging/*"):
            if not _writer_alive(staging.name):  # a version a killed writer left half-written
                shutil.rmtree(staging, ignore_errors=True)

    # ------------------------------------------------------------------ reading
    def names(self) -> list[str]:
        """Map names with at least one complete version, sorted."""
        return sorted(p.name for p in self.root.iterdir()
                      if p.is_dir() and NAME_RE.match(p.name) and self.versions(p.name))

    def _dir(self, name: str) -> Path:
        return self.root / check_name(name)

    def versions(self, name: str) -> list[MapVersionInfo]:
        """Complete versions of `name`, oldest first (by publication time)."""
        vdir = self._dir(name) / "versions"
        if not vdir.is_dir():
            return []
        out = [self.info(name, p.name) for p in vdir.iterdir() if VERSION_RE.match(p.name)
               and (p / "version.json").is_file()]
        return sorted(out, key=lambda v: (v.created_ns, v.version))

    def _record(self, name: str, version: str) -> dict[str, Any]:
        path = self._dir(name) / "versions" / version / "version.json"
        if not VERSION_RE.match(version) or not path.is_file():
            raise MapServiceError(MapErrorKind.NOT_FOUND, f"map {name!r} has no version {version!r}")
        rec: dict[str, Any] = json.loads(path.read_text(encoding="utf-8"))
        return rec

    def info(self, name: str, version: str) -> MapVersionInfo:
        return MapVersionInfo.from_json(self._record(name, version)["info"])

    def manifest(self, name: str, version: str) -> TransferManifest:
        """The transfer manifest (files, chunks, chunk size) of a version."""
        return TransferManifest.from_json(self._record(name, version)["transfer"])

    def map_path(self, name: str, version: str) -> Path:
        """The folder of a complete version (read it, never write it)."""
        vdir = self._dir(name) / "versions" / version
        if not VERSION_RE.match(version) or not (vdir / "version.json").is_file():
            raise MapServiceError(MapErrorKind.NOT_FOUND, f"map {name!r} has no version {version!r}")
        return vdir / "map"

    def resolve(self, name: str, version: str) -> str:
        """The full version id of `version` (full id or a unique prefix of >= 8 hex digits)."""
        if VERSION_RE.match(version):
            self._record(name, version)
            return version
        if len(version) < MIN_PREFIX or not re.fullmatch(r"[0-9a-f]+", version):
            raise MapServiceError(MapErrorKind.BAD_REQUEST,
                                  f"version {version!r}: give the hash or at least {MIN_PREFIX} of its hex digits")
        hits = [v.version for v in self.versions(name) if v.version.startswith(version)]
        if len(hits) != 1:
            raise MapServiceError(MapErrorKind.NOT_FOUND if not hits else MapErrorKind.BAD_REQUEST,
                                  f"map {name!r}: {len(hits)} versions start with {version!r}")
        return hits[0]

    def latest(self, name: str) -> MapVersionInfo:
        path = self._dir(name) / "latest.json"
        if not path.is_file():
            raise MapServiceError(MapErrorKind.NOT_FOUND, f"no map named {name!r}")
        return self.info(name, json.loads(path.read_text(encoding="utf-8"))["version"])

    def history(self, name: str) -> list[dict[str, Any]]:
        """Moves of `latest`, oldest first: {"t_ns", "action": "publish"|"rollback", "version", "from"}."""
        path = self._dir(name) / "history.jsonl"
        if not path.is_file():
            return []
        out = []
        for line in path.read_text(encoding="utf-8").splitlines():
            try:
                out.append(json.loads(line))
            except json.JSONDecodeError:
                continue  # a line cut by a crash mid-append: the move it describes is in latest.json or not at all
        return out

    # ------------------------------------------------------------------ writing
    def add_version(self, name: str, src: str | Path, parent: str | None = None, move: bool = False,
                    expect: MapVersionInfo | None = None, make_latest: bool = True) -> MapVersionInfo:
        """Add the map folder `src` as a version of `name` (copied, or renamed with `move`).

        `parent`: defaults to the current latest. `expect`: the info of a fetched version, whose
        hash the files must have (else `MapServiceError(CHECKSUM)`) and which is stored as it is.
        An existing identical version is returned unchanged (never rewritten). `make_latest`:
        move `latest` to it."""
        ndir = self._dir(name)
        src = Path(src)
        entries = file_entries(src)
        check_map_folder(src, entries)
        version = content_hash(entries)
        if expect is not None and version != expect.version:
            raise MapServiceError(MapErrorKind.CHECKSUM, f"{src}: files hash to {version}, expected "
                                  f"{expect.version}")
        final = ndir / "versions" / version
        if not (final / "version.json").is_file():
            if parent is None and (ndir / "latest.json").is_file():
                parent = self.latest(name).version
            info = expect or MapVersionInfo(name, version, parent, sum(e["bytes"] for e in entries.values()),
                                            time.time_ns())
            staging = ndir / ".staging" / f"{os.getpid()}-{uuid.uuid4().hex}"
            staging.mkdir(parents=True)
            try:
                self._stage(src, staging, move, version, info, entries)
                (ndir / "versions").mkdir(exist_ok=True)
                os.rename(staging, final)
            except BaseException as exc:
                shutil.rmtree(staging, ignore_errors=True)
                if not (isinstance(exc, OSError) and (final / "version.json").is_file()):
                    raise  # (an OSError with the version in place: a concurrent identical publish won)
            _fsync_dir(final.parent)
        elif move:
            shutil.rmtree(src)
        info = self.info(name, version)
        if make_latest:
            self.set_latest(name, version, "publish")
        return info

    def _stage(self, src: Path, staging: Path, move: bool, version: str, info: MapVersionInfo,
               entries: dict[str, dict[str, Any]]) -> None:
        if move:
            src.rename(staging / "map")
        else:
            shutil.copytree(src, staging / "map")
        if content_hash(file_entries(staging / "map")) != version:
            raise MapServiceError(MapErrorKind.CHECKSUM, f"{src}: files changed while being stored")
        transfer = transfer_manifest(staging / "map", self.chunk_bytes, entries)
        rec = {"info": info.to_json(), "transfer": transfer.to_json()}
        (staging / "version.json").write_text(json.dumps(rec, sort_keys=True), encoding="utf-8")
        _fsync_tree(staging)

    def rollback(self, name: str, version: str) -> MapVersionInfo:
        """Move `latest` of `name` to an existing `version` (older or not); nothing is deleted."""
        full = self.resolve(name, version)
        self.set_latest(name, full, "rollback")
        return self.info(name, full)

    def set_latest(self, name: str, version: str, action: str) -> None:
        """Point `latest` of `name` at the complete `version` (`action` goes to the history)."""
        self._record(name, version)
        ndir = self._dir(name)
        path = ndir / "latest.json"
        before = json.loads(path.read_text(encoding="utf-8"))["version"] if path.is_file() else None
        if before == version:
            return
        write_json_atomic(path, {"version": version})
        with open(ndir / "history.jsonl", "a", encoding="utf-8") as f:
            f.write(json.dumps({"t_ns": time.time_ns(), "action": action, "version": version, "from": before}) + "\n")
            f.flush()
            os.fsync(f.fileno())
