"""Transfer manifests from a peer are checked before anything is written: paths stay inside the
folder, chunks tile every file exactly, the file list hashes to the content hash."""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import pytest

from litevloc.runtime.maps.errors import MapErrorKind, MapServiceError
from litevloc.runtime.maps.store import MapVersionInfo
from litevloc.runtime.maps.transfer import TransferManifest, content_hash, transfer_manifest
from tests.runtime.maps.conftest import tiny_map


def _bad(d: Any) -> None:
    with pytest.raises(MapServiceError) as e:
        TransferManifest.from_json(d)
    assert e.value.kind is MapErrorKind.BAD_REPLY


def test_manifest_round_trip_and_refusals(tmp_path: Path) -> None:
    m = transfer_manifest(tiny_map(tmp_path / "a"), 4096)
    d = m.to_json()
    assert TransferManifest.from_json(d) == m and m.content_hash == content_hash(m.files)
    for rel in ("../escape.bin", "/etc/passwd", "a/../../b", "x\\y"):
        evil = copy.deepcopy(d)
        evil["files"][rel] = evil["files"].pop("nodes/blob.bin")
        evil["content_hash"] = content_hash(evil["files"])
        _bad(evil)
    gap = copy.deepcopy(d)
    gap["chunks"] = [c for c in gap["chunks"] if not (c[0] == "nodes/blob.bin" and c[1] == 4096)]
    _bad(gap)
    short = copy.deepcopy(d)
    short["chunks"].pop()
    _bad(short)
    other = copy.deepcopy(d)
    other["content_hash"] = "0" * 64
    _bad(other)
    for junk in (None, [], {"files": 3}, {**d, "chunks": [[1, 2]]}):
        _bad(junk)


def test_version_info_from_a_peer_is_checked() -> None:
    ok = {"name": "office", "version": "a" * 64, "parent": None, "size_bytes": 10, "created_ns": 1}
    assert MapVersionInfo.from_json(ok).name == "office"
    for bad in ({**ok, "name": "../x"}, {**ok, "version": "abc"}, {**ok, "size_bytes": -1}, {**ok, "parent": 3},
                {**ok, "created_ns": "now"}, [], None):
        with pytest.raises(MapServiceError):
            MapVersionInfo.from_json(bad)
