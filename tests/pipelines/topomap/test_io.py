"""Map format: round trip, byte-identical rebuilds, one test per kind of corruption."""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from litevloc.pipelines.topomap.build import MappingParams
from litevloc.pipelines.topomap.io import MapFormatError, load_map, save_map, storage_summary
from litevloc.pipelines.topomap.types import TopoMap

from .helpers import SEVEN_SCENES_UP, build_7scenes

PARAMS = MappingParams(up=SEVEN_SCENES_UP)


@pytest.fixture(scope="module")
def built_map(seven_scenes_dir: Path) -> TopoMap:
    return build_7scenes(seven_scenes_dir, "0:200:2", PARAMS).finish()


@pytest.fixture(scope="module")
def saved_map(built_map: TopoMap, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return save_map(built_map, tmp_path_factory.mktemp("maps") / "m")


def assert_same(a: object, b: object, where: str) -> None:
    """Field-by-field equality of maps (dataclasses, arrays with dtype, lists, bytes)."""
    if dataclasses.is_dataclass(a) and not isinstance(a, type):
        assert type(a) is type(b), where
        for f in dataclasses.fields(a):
            assert_same(getattr(a, f.name), getattr(b, f.name), f"{where}.{f.name}")
    elif isinstance(a, np.ndarray) and where == "map.vpr":
        # stored as int8 codes with one scale per row (documented lossy): within one quantisation
        # step of a unit vector (1/127), and the same retrieval geometry
        assert isinstance(b, np.ndarray) and b.shape == a.shape and b.dtype == a.dtype, where
        np.testing.assert_allclose(b, a, atol=1 / 127, rtol=0, err_msg=where)
        assert np.all(np.sum(a * b, axis=1) > 0.9999), where
    elif isinstance(a, np.ndarray) and where.endswith(".descriptors") and a.dtype == np.float32:
        # float descriptors are stored as float16 (documented): exactly the float16 rounding
        assert isinstance(b, np.ndarray) and b.shape == a.shape, where
        np.testing.assert_array_equal(np.asarray(b, np.float32), a.astype(np.float16).astype(np.float32),
                                      err_msg=where)
    elif isinstance(a, np.ndarray):
        assert isinstance(b, np.ndarray) and a.dtype == b.dtype, (where, a.dtype, getattr(b, "dtype", None))
        np.testing.assert_array_equal(a, b, err_msg=where)
    elif isinstance(a, list | tuple):
        assert len(a) == len(b), where  # type: ignore[arg-type]
        for i, (x, y) in enumerate(zip(a, b, strict=True)):  # type: ignore[call-overload]
            assert_same(x, y, f"{where}[{i}]")
    else:
        assert a == b, (where, a, b)


def copy(src: Path, tmp: Path) -> Path:
    dst = tmp / "copy"
    shutil.copytree(src, dst)
    return dst


def rewrite_manifest(folder: Path, fn) -> None:  # type: ignore[no-untyped-def]
    p = folder / "manifest.json"
    man = json.loads(p.read_text())
    fn(man)
    p.write_text(json.dumps(man))


def test_round_trip_and_summary(built_map: TopoMap, saved_map: Path) -> None:
    m = load_map(saved_map)
    assert_same(built_map, m, "map")  # what was saved is what loads: every array, feature, image, edge
    assert 3 <= m.n_nodes <= 40 and len(m.images_jpeg) == m.n_nodes and len(m.features) == m.n_nodes
    assert np.all(np.diff(m.t_ns) > 0)  # nodes in time order
    assert len(m.conn_edges) >= m.n_nodes - 1  # consecutive keyframes are always connected
    s = storage_summary(saved_map)
    assert s["graph_bytes"] + s["descriptor_bytes"] < 100_000 and s["image_bytes"] > 0


def test_rebuild_is_byte_identical(seven_scenes_dir: Path, saved_map: Path, tmp_path: Path) -> None:
    m = build_7scenes(seven_scenes_dir, "0:200:2", PARAMS).finish()
    other = save_map(m, tmp_path / "again")
    a = json.loads((saved_map / "manifest.json").read_text())["files"]
    b = json.loads((other / "manifest.json").read_text())["files"]
    assert a == b  # same sha256 for every array and image


@pytest.mark.parametrize(
    ("damage", "pattern"),
    [
        (lambda d: (d / "features/keypoints.npy").unlink(), r"features/keypoints\.npy: missing"),
        (lambda d: (d / "vpr/descriptors.npy").write_bytes((d / "vpr/descriptors.npy").read_bytes()[:-40]),
         r"vpr/descriptors\.npy: truncated"),
        (lambda d: (d / "images/000001.jpg").write_bytes(b"\xff\xd8" + bytes(100)), r"images/000001\.jpg: truncated"),
        (lambda d: (d / "manifest.json").write_text("{not json"), r"manifest\.json: not valid JSON"),
        (lambda d: (d / "manifest.json").unlink(), r"manifest\.json: missing"),
    ],
)
def test_corruption_is_named(saved_map: Path, tmp_path: Path, damage, pattern: str) -> None:  # type: ignore[no-untyped-def]
    d = copy(saved_map, tmp_path)
    damage(d)
    with pytest.raises(MapFormatError, match=pattern):
        load_map(d)


def test_checksum_mismatch(saved_map: Path, tmp_path: Path) -> None:
    d = copy(saved_map, tmp_path)
    p = d / "nodes/T_map_camera.npy"
    data = bytearray(p.read_bytes())
    data[-3] ^= 0x01
    p.write_bytes(bytes(data))
    with pytest.raises(MapFormatError, match=r"nodes/T_map_camera\.npy: checksum mismatch"):
        load_map(d)


def _replace_array(d: Path, rel: str, a: np.ndarray) -> None:
    import hashlib
    import io

    buf = io.BytesIO()
    np.save(buf, a)
    data = buf.getvalue()
    (d / rel).write_bytes(data)
    rewrite_manifest(d, lambda m: m["files"].__setitem__(rel, {"sha256": hashlib.sha256(data).hexdigest(),
                                                                 "bytes": len(data)}))


def test_wrong_version(saved_map: Path, tmp_path: Path) -> None:
    d = copy(saved_map, tmp_path)
    rewrite_manifest(d, lambda m: m.__setitem__("version", 99))
    with pytest.raises(MapFormatError, match="unsupported map version 99"):
        load_map(d)


def test_wrong_shape_dtype_and_values(saved_map: Path, tmp_path: Path) -> None:
    m = load_map(saved_map)
    d = copy(saved_map, tmp_path)
    _replace_array(d, "nodes/K.npy", m.K[:-1])
    with pytest.raises(MapFormatError, match=r"nodes/K\.npy: shape"):
        load_map(d)
    d2 = copy(saved_map, tmp_path / "b")
    _replace_array(d2, "graph/connectivity_metres.npy", m.conn_metres.astype(np.float64))
    with pytest.raises(MapFormatError, match=r"connectivity_metres\.npy: dtype float64"):
        load_map(d2)
    d3 = copy(saved_map, tmp_path / "c")
    bad = m.covis_edges.copy() if len(m.covis_edges) else np.array([[0, 1]], np.int64)
    bad[0, 1] = m.n_nodes + 5
    _replace_array(d3, "graph/covisibility_edges.npy", bad)
    if len(m.covis_edges) == 0:
        rewrite_manifest(d3, lambda man: None)
    with pytest.raises(MapFormatError, match="covisibility"):
        load_map(d3)
    d4 = copy(saved_map, tmp_path / "d")
    T = m.T_map_camera.copy()
    T[0, 0, 0] = np.nan
    _replace_array(d4, "nodes/T_map_camera.npy", T)
    with pytest.raises(MapFormatError, match="NaN"):
        load_map(d4)


def test_pickled_array_is_refused(saved_map: Path, tmp_path: Path) -> None:
    d = copy(saved_map, tmp_path)
    _replace_array(d, "vpr/descriptors.npy", np.array([{"a": 1}], dtype=object))
    with pytest.raises(MapFormatError, match=r"vpr/descriptors\.npy"):
        load_map(d)
