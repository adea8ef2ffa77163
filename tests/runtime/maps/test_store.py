"""The versioned map store: content-addressed immutable versions, atomic writes (a writer killed
mid-version leaves the previous version served and nothing half-written), latest and rollback."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from litevloc.runtime.maps.errors import MapErrorKind, MapServiceError
from litevloc.runtime.maps.store import MapStore
from litevloc.runtime.maps.transfer import content_hash, file_entries
from tests.runtime.maps.conftest import tiny_map


def test_versions_are_content_addressed_and_never_rewritten(tmp_path: Path) -> None:
    store = MapStore(tmp_path / "store", chunk_bytes=4096)
    a = tiny_map(tmp_path / "a", seed=1)
    v1 = store.add_version("office", a)
    assert v1.version == content_hash(file_entries(a)) and v1.parent is None
    assert v1.size_bytes == sum(e["bytes"] for e in file_entries(a).values())
    before = file_entries(store.map_path("office", v1.version))
    again = store.add_version("office", a)  # same bytes: the same version, untouched
    assert again == v1 and file_entries(store.map_path("office", v1.version)) == before
    b = tiny_map(tmp_path / "b", seed=2)
    v2 = store.add_version("office", b)
    assert v2.version != v1.version and v2.parent == v1.version
    assert store.latest("office") == v2
    assert [v.version for v in store.versions("office")] == [v1.version, v2.version]
    assert file_entries(store.map_path("office", v1.version)) == before
    assert store.manifest("office", v2.version).content_hash == v2.version


def test_rollback_moves_latest_and_keeps_every_version(tmp_path: Path) -> None:
    store = MapStore(tmp_path / "store", chunk_bytes=4096)
    v1 = store.add_version("office", tiny_map(tmp_path / "a", seed=1))
    v2 = store.add_version("office", tiny_map(tmp_path / "b", seed=2))
    assert store.rollback("office", v1.version[:10]) == v1
    assert store.latest("office") == v1 and len(store.versions("office")) == 2
    assert [h["action"] for h in store.history("office")] == ["publish", "publish", "rollback"]
    assert store.history("office")[-1]["from"] == v2.version
    # a restart (a new store object on the same folder) serves what was there
    assert MapStore(tmp_path / "store").latest("office") == v1
    with pytest.raises(MapServiceError) as e:
        store.rollback("office", "0" * 64)
    assert e.value.kind is MapErrorKind.NOT_FOUND
    with pytest.raises(MapServiceError) as e:
        store.rollback("office", "ab")
    assert e.value.kind is MapErrorKind.BAD_REQUEST


def test_bad_names_and_non_map_folders_are_refused(tmp_path: Path) -> None:
    store = MapStore(tmp_path / "store")
    for bad in ("", "../x", "a/b", "_index", "*"):
        with pytest.raises(MapServiceError):
            store.add_version(bad, tiny_map(tmp_path / "a"))
    (tmp_path / "empty").mkdir()
    with pytest.raises(MapServiceError) as e:
        store.add_version("office", tmp_path / "empty")
    assert e.value.kind is MapErrorKind.BAD_REQUEST
    # a map whose files are not what its manifest lists (damaged, half-copied, edited) is refused
    for damage in ("modify", "extra", "remove"):
        m = tiny_map(tmp_path / damage)
        if damage == "modify":
            (m / "nodes/blob.bin").write_bytes(b"other bytes")
        elif damage == "extra":
            (m / "notes.txt").write_text("x")
        else:
            (m / "images/000000.jpg").unlink()
        with pytest.raises(MapServiceError) as e:
            store.add_version("office", m)
        assert e.value.kind is MapErrorKind.BAD_REQUEST, damage
    assert store.versions("office") == []


def test_failure_while_writing_leaves_the_previous_version(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    store = MapStore(tmp_path / "store", chunk_bytes=4096)
    v1 = store.add_version("office", tiny_map(tmp_path / "a", seed=1))

    def boom(*a: object) -> None:
        raise OSError("disk full")

    monkeypatch.setattr("litevloc.runtime.maps.store._fsync_tree", boom)
    with pytest.raises(OSError):
        store.add_version("office", tiny_map(tmp_path / "b", seed=2))
    monkeypatch.undo()
    again = MapStore(tmp_path / "store")
    assert again.latest("office") == v1 and [v.version for v in again.versions("office")] == [v1.version]
    assert not list((tmp_path / "store" / "office" / ".staging").glob("*"))


_WRITER = textwrap.dedent("""
    import os, sys, time
    from litevloc.runtime.maps import store as st
    real = st._fsync_tree
    def slow(root):
        real(root)
        print("STAGED", flush=True)
        time.sleep(60)  # killed here: every byte written, the version not renamed into place
    st._fsync_tree = slow
    st.MapStore(sys.argv[1]).add_version("office", sys.argv[2])
""")


def test_sigkill_during_a_write_serves_the_previous_version_after_restart(tmp_path: Path) -> None:
    root = tmp_path / "store"
    v1 = MapStore(root).add_version("office", tiny_map(tmp_path / "a", seed=1))
    proc = subprocess.Popen([sys.executable, "-c", _WRITER, str(root), str(tiny_map(tmp_path / "b", seed=2))],
                            stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None and proc.stdout.readline().strip() == "STAGED"
    assert list((root / "office" / ".staging").iterdir())  # the half-published version is on disk ...
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait(10)
    after = MapStore(root)  # ... and a restart neither lists nor keeps it
    assert after.latest("office") == v1 and [v.version for v in after.versions("office")] == [v1.version]
    assert not list((root / "office" / ".staging").iterdir())
