"""Map folders: corrupt files, corrupt manifests, and well-checksummed but wrong arrays all
raise MapFormatError (never another exception, never a silently wrong map)."""

from __future__ import annotations

import hashlib
import io
import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from litevloc.pipelines.topomap.io import MapFormatError, load_map
from litevloc.pipelines.topomap.map_save import save_map
from tests.pipelines.localization.test_vloc import make_map


@pytest.fixture(scope="module", params=[0, 1], ids=["int8", "pq"])
def good_map(tmp_path_factory: pytest.TempPathFactory, request: pytest.FixtureRequest) -> Path:
    """A valid map in each float-descriptor encoding: int8 codes (format 2's) and product-
    quantiser codes with their codebook (format 3's default; one byte for these 17-d descriptors)."""
    d = tmp_path_factory.mktemp("fuzzmap") / "map"
    import dataclasses

    import cv2

    ok, jpg = cv2.imencode(".jpg", np.full((24, 32, 3), 128, np.uint8))
    assert ok
    m = make_map([0.0, 1.0, 2.0])
    # the localizer tests' descriptors carry point ids (up to ~1e5): scaled into float16's range,
    # the map format's descriptor storage, so the good map is a valid map
    feats = [dataclasses.replace(f, descriptors=f.descriptors / 1e5) for f in m.features]
    save_map(dataclasses.replace(m, features=feats, images_jpeg=[jpg.tobytes()] * m.n_nodes), d,
             descriptor_bytes=request.param)
    codec = json.loads((d / "manifest.json").read_text())["descriptor_codec"]
    assert codec == ("int8" if request.param == 0 else "pq")
    load_map(d)
    return d


def _files(folder: Path) -> list[str]:
    return sorted(json.loads((folder / "manifest.json").read_text())["files"])


def _copy(src: Path, tmp: Path, n: int) -> Path:
    dst = tmp / f"m{n}"
    if dst.exists():
        shutil.rmtree(dst)
    shutil.copytree(src, dst)
    return dst


def _rehash(folder: Path, rel: str) -> None:
    man = json.loads((folder / "manifest.json").read_text())
    data = (folder / rel).read_bytes()
    man["files"][rel] = {"sha256": hashlib.sha256(data).hexdigest(), "bytes": len(data)}
    (folder / "manifest.json").write_text(json.dumps(man))


def _check_loaded(m: Any) -> None:
    """A map that loads must be self-consistent."""
    n = m.n_nodes
    assert m.T_map_camera.shape == (n, 4, 4) and np.all(np.isfinite(m.T_map_camera))
    R = m.T_map_camera[:, :3, :3]
    assert np.allclose(R.transpose(0, 2, 1) @ R, np.eye(3), atol=1e-4) and np.allclose(np.linalg.det(R), 1, atol=1e-4)
    assert np.allclose(m.T_map_camera[:, 3], [0, 0, 0, 1])
    assert m.K.shape == (n, 3, 3) and len(m.features) == n and m.vpr.shape[0] == n
    assert np.all(m.K[:, 0, 0] > 0) and np.all(m.K[:, 1, 1] > 0) and np.all(np.isfinite(m.K))
    assert np.all(np.isfinite(m.vpr))
    for e in (m.covis_edges, m.conn_edges):
        assert e.size == 0 or (e.min() >= 0 and e.max() < n)
    for f in m.features:
        assert len(f.keypoints) == len(f.descriptors) == len(f.scores)


_N = [0]


@settings(max_examples=60)
@given(data=st.data())
def test_corrupted_file_bytes(good_map: Path, tmp_path: Path, count_case: Any, data: st.DataObject) -> None:
    """Random byte edits / truncation of any file: the checksum (or the manifest parser) refuses it."""
    count_case()
    _N[0] += 1
    d = _copy(good_map, tmp_path, _N[0])
    rel = data.draw(st.sampled_from([*_files(d), "manifest.json"]))
    raw = bytearray((d / rel).read_bytes())
    op = data.draw(st.sampled_from(["truncate", "flip", "append"]))
    if op == "truncate":
        raw = raw[: data.draw(st.integers(0, max(0, len(raw) - 1)))]
    elif op == "flip":
        i = data.draw(st.integers(0, len(raw) - 1))
        raw[i] ^= data.draw(st.integers(1, 255))
    else:
        raw += data.draw(st.binary(min_size=1, max_size=16))
    (d / rel).write_bytes(bytes(raw))
    try:
        m = load_map(d)
    except MapFormatError:
        return
    assert rel == "manifest.json"  # only a harmless manifest edit (e.g. whitespace) may still load
    _check_loaded(m)


json_values = st.recursive(st.none() | st.booleans() | st.integers(-5, 10**6) | st.floats() | st.text(max_size=8),
                           lambda c: st.lists(c, max_size=3) | st.dictionaries(st.text(max_size=8), c, max_size=3),
                           max_leaves=5)


@settings(max_examples=60)
@given(data=st.data())
def test_fuzzed_manifest_fields(good_map: Path, tmp_path: Path, count_case: Any, data: st.DataObject) -> None:
    count_case()
    _N[0] += 1
    d = _copy(good_map, tmp_path, _N[0])
    man = json.loads((d / "manifest.json").read_text())
    key = data.draw(st.sampled_from(sorted(man)))
    man[key] = data.draw(json_values)
    if data.draw(st.booleans()):  # also point a file entry somewhere odd
        rel = data.draw(st.sampled_from(sorted(man.get("files", {}) or {"x": 0})))
        if isinstance(man.get("files"), dict):
            man["files"][data.draw(st.sampled_from([rel, "../outside.npy", "/etc/passwd"]))] = data.draw(json_values)
    (d / "manifest.json").write_text(json.dumps(man))
    try:
        m = load_map(d)
    except MapFormatError:
        return
    _check_loaded(m)


def _random_npy(data: st.DataObject) -> bytes:
    dtype = data.draw(st.sampled_from(["float64", "float32", "int64", "int32", "uint8", "int8", "bool", "<U3"]))
    shape = tuple(data.draw(st.lists(st.integers(0, 5), min_size=0, max_size=3)))
    a = np.zeros(shape, dtype=dtype)
    if a.size and a.dtype.kind in "fiu":
        vals = data.draw(st.lists(st.floats(-1e6, 1e6) | st.just(float("nan")), min_size=a.size, max_size=a.size))
        a = np.nan_to_num(np.array(vals), nan=0.0).astype(dtype).reshape(shape) if a.dtype.kind in "iu" else \
            np.array(vals, dtype=dtype).reshape(shape)
    buf = io.BytesIO()
    np.save(buf, a, allow_pickle=False)
    return buf.getvalue()


@settings(max_examples=150)
@given(data=st.data())
def test_wrong_arrays_with_valid_checksums(good_map: Path, tmp_path: Path, count_case: Any,
                                           data: st.DataObject) -> None:
    """An array file replaced by another array (or an object/pickle .npy) and re-hashed in the
    manifest: the structural checks refuse it, or what loads is consistent."""
    count_case()
    _N[0] += 1
    d = _copy(good_map, tmp_path, _N[0])
    rel = data.draw(st.sampled_from([f for f in _files(d) if f.endswith(".npy")]))
    if data.draw(st.integers(0, 9)) == 0:
        # an object-dtype .npy (what a pickle inside .npy declares), built by hand so the test
        # never pickles anything; the loader must refuse it from the header alone
        buf = io.BytesIO()
        np.lib.format.write_array_header_1_0(buf, {"descr": "|O", "fortran_order": False, "shape": (1,)})
        payload = buf.getvalue() + b"opaque object payload, never unpickled"
    elif data.draw(st.booleans()):  # same array, values perturbed (NaN, out-of-range indices, ...)
        a = np.load(d / rel, allow_pickle=False)
        if a.size:
            flat = a.reshape(-1).copy()
            i = data.draw(st.integers(0, flat.size - 1))
            if a.dtype.kind == "f":
                with np.errstate(over="ignore"):
                    flat[i] = data.draw(st.sampled_from([np.nan, np.inf, -1e9, 1e9, 0.5, -1.0]))
            elif a.dtype.kind in "iu":
                info = np.iinfo(a.dtype)
                flat[i] = data.draw(st.sampled_from([max(-1, int(info.min)), int(info.max), int(info.max) // 2]))
            a = flat.reshape(a.shape)
        buf = io.BytesIO()
        np.save(buf, a, allow_pickle=False)
        payload = buf.getvalue()
    else:
        payload = _random_npy(data)
    (d / rel).write_bytes(payload)
    _rehash(d, rel)
    try:
        m = load_map(d)
    except MapFormatError:
        return
    _check_loaded(m)
