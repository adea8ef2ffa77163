"""Content hashes and the chunked transfer of a folder of files (a map, or a pushed recording).

A folder is described by its file list `{relative posix path: {"sha256", "bytes"}}`; its
content hash (the map version) is the sha256 of that list as canonical JSON (sorted keys, no
spaces). For transfer the files, in path order, are cut into chunks of `chunk_bytes` (a chunk
never spans two files; a file's last chunk is shorter), each with its sha256. The receiver
writes chunk bytes at their offsets and checks each chunk, then every file, then the content
hash: a resumed transfer keeps the chunks whose bytes on disk already hash right.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import Any

from litevloc.runtime.maps.errors import MapErrorKind, MapServiceError

READ_BLOCK = 1 << 20
MAX_FILES = 1_000_000


def sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while block := f.read(READ_BLOCK):
            h.update(block)
    return h.hexdigest()


def file_entries(folder: Path) -> dict[str, dict[str, Any]]:
    """`{rel: {"sha256", "bytes"}}` of every regular file under `folder` (symlinks refused)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise MapServiceError(MapErrorKind.NOT_FOUND, f"{folder}: not a folder")
    out: dict[str, dict[str, Any]] = {}
    for dirpath, dirs, files in os.walk(folder):
        dirs.sort()
        for f in sorted(files):
            p = Path(dirpath) / f
            if p.is_symlink() or not p.is_file():
                raise MapServiceError(MapErrorKind.BAD_REQUEST, f"{p}: only regular files can be stored")
            out[p.relative_to(folder).as_posix()] = {"sha256": sha256_file(p), "bytes": p.stat().st_size}
    return dict(sorted(out.items()))


def content_hash(entries: dict[str, dict[str, Any]]) -> str:
    """sha256 (hex) of the canonical JSON of a file list: the version id of those files."""
    canon = {k: {"bytes": int(v["bytes"]), "sha256": str(v["sha256"])} for k, v in sorted(entries.items())}
    return hashlib.sha256(json.dumps(canon, sort_keys=True, separators=(",", ":")).encode()).hexdigest()


def safe_relpath(rel: Any) -> str:
    """`rel` if it is a relative posix path inside its folder, else `MapServiceError(BAD_REPLY)`."""
    p = PurePosixPath(rel) if isinstance(rel, str) else None
    if p is None or not rel or p.is_absolute() or ".." in p.parts or "\\" in rel or "\x00" in rel:
        raise MapServiceError(MapErrorKind.BAD_REPLY, f"unsafe file path in a transfer manifest: {rel!r}")
    return str(p)


@dataclass(frozen=True)
class Chunk:
    """Bytes [offset, offset + size) of file `path`, whose sha256 is `sha256`."""

    path: str
    offset: int
    size: int
    sha256: str


@dataclass(frozen=True)
class TransferManifest:
    """What a receiver needs: the files (path -> sha256, bytes), the chunks in order, the chunk size
    and the content hash of the file list."""

    content_hash: str
    chunk_bytes: int
    files: dict[str, dict[str, Any]]
    chunks: tuple[Chunk, ...]

    @property
    def size_bytes(self) -> int:
        return sum(int(e["bytes"]) for e in self.files.values())

    def to_json(self) -> dict[str, Any]:
        return {"content_hash": self.content_hash, "chunk_bytes": self.chunk_bytes, "files": self.files,
                "chunks": [[c.path, c.offset, c.size, c.sha256] for c in self.chunks]}

    @classmethod
    def from_json(cls, d: Any) -> TransferManifest:
        """Parse and check a manifest from a peer: safe paths, chunks that tile every file exactly."""
        try:
            files: dict[str, dict[str, Any]] = {safe_relpath(k): {"sha256": str(v["sha256"]), "bytes": int(v["bytes"])}
                                                for k, v in dict(d["files"]).items()}
            chunks = tuple(Chunk(safe_relpath(c[0]), int(c[1]), int(c[2]), str(c[3])) for c in d["chunks"])
            m = cls(str(d["content_hash"]), int(d["chunk_bytes"]), files, chunks)
        except (KeyError, TypeError, ValueError, IndexError) as exc:
            raise MapServiceError(MapErrorKind.BAD_REPLY, f"malformed transfer manifest: {exc}") from exc
        if len(files) > MAX_FILES or m.chunk_bytes < 1 or content_hash(files) != m.content_hash:
            raise MapServiceError(MapErrorKind.BAD_REPLY, "transfer manifest: file list does not hash to its "
                                  "content hash (or is out of bounds)")
        next_off = dict.fromkeys(files, 0)
        for c in chunks:
            if c.path not in files or c.offset != next_off[c.path] or not 0 < c.size <= m.chunk_bytes:
                raise MapServiceError(MapErrorKind.BAD_REPLY, f"transfer manifest: chunk {c} does not tile its file")
            next_off[c.path] += c.size
        if any(next_off[k] != int(files[k]["bytes"]) for k in files):
            raise MapServiceError(MapErrorKind.BAD_REPLY, "transfer manifest: chunks do not cover every file")
        return m


def transfer_manifest(folder: Path, chunk_bytes: int, entries: dict[str, dict[str, Any]] | None = None
                      ) -> TransferManifest:
    """Cut the files of `folder` into chunks of `chunk_bytes` and hash each chunk."""
    entries = file_entries(folder) if entries is None else entries
    chunks = []
    for rel, e in entries.items():
        with open(folder / rel, "rb") as f:
            off = 0
            while off < int(e["bytes"]):
                data = f.read(chunk_bytes)
                chunks.append(Chunk(rel, off, len(data), hashlib.sha256(data).hexdigest()))
                off += len(data)
    return TransferManifest(content_hash(entries), chunk_bytes, entries, tuple(chunks))


def read_chunk(folder: Path, c: Chunk) -> bytes:
    with open(folder / c.path, "rb") as f:
        f.seek(c.offset)
        return f.read(c.size)


def chunk_on_disk(folder: Path, c: Chunk) -> bool:
    """True when `folder` already holds chunk `c`'s bytes (a resumed transfer keeps it)."""
    p = folder / c.path
    if not p.is_file() or p.stat().st_size < c.offset + c.size:
        return False
    return hashlib.sha256(read_chunk(folder, c)).hexdigest() == c.sha256


def write_chunk(folder: Path, c: Chunk, data: bytes) -> None:
    """Write chunk bytes at their offset (file created as needed); caller checked the hash."""
    p = folder / c.path
    p.parent.mkdir(parents=True, exist_ok=True)
    with open(p, "r+b" if p.exists() else "wb") as f:
        f.seek(c.offset)
        f.write(data)


def check_files(folder: Path, m: TransferManifest) -> None:
    """Every file of `m` complete and hashing right, no extra file, the whole list hashing to
    `m.content_hash`; else `MapServiceError(CHECKSUM)` naming the first bad file."""
    got = file_entries(folder)
    for rel, e in m.files.items():
        if rel not in got:
            raise MapServiceError(MapErrorKind.CHECKSUM, f"{folder}: {rel} missing after transfer")
        if got[rel] != {"sha256": e["sha256"], "bytes": int(e["bytes"])}:
            raise MapServiceError(MapErrorKind.CHECKSUM, f"{folder}: {rel} does not match its sha256/size")
    extra = sorted(set(got) - set(m.files))
    if extra or content_hash(got) != m.content_hash:
        raise MapServiceError(MapErrorKind.CHECKSUM, f"{folder}: files do not hash to {m.content_hash} "
                              f"(unexpected: {extra[:3]})")
