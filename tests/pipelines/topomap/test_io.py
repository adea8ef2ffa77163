"""Map format: round trip, byte-identical rebuilds, one test per kind of corruption."""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from litevloc.pipelines.topomap.io import MapFormatError, load_map, storage_summary
from litevloc.pipelines.topomap.map_save import save_map
from litevloc.pipelines.topomap.types import TopoMap

from .helpers import build_7scenes, seven_scenes_mapping

PARAMS = seven_scenes_mapping(budget=None, coverage=0.95, cell_m=0.25, heading_bins=8)


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
        # float descriptors are stored as int8 codes with one scale per row (documented): exactly
        # that rounding, within half a step of each row's largest value
        from litevloc.pipelines.topomap.map_save import quantise

        assert isinstance(b, np.ndarray) and b.shape == a.shape, where
        codes, scale = quantise(a)
        np.testing.assert_array_equal(np.asarray(b, np.float32), codes.astype(np.float32) * scale[:, None],
                                      err_msg=where)
    elif isinstance(a, np.ndarray) and where.endswith(".keypoints"):
        # stored as uint16 steps of 1/8 px (documented): exactly that rounding, within 1/16 px
        from litevloc.pipelines.topomap.types import keypoints_from_fixed, keypoints_to_fixed

        assert isinstance(b, np.ndarray) and b.shape == a.shape and b.dtype == np.float32, where
        np.testing.assert_array_equal(b, keypoints_from_fixed(keypoints_to_fixed(a)), err_msg=where)
        assert float(np.abs(b - a).max(initial=0)) <= 1 / 16 + 1e-4, where
    elif isinstance(a, np.ndarray) and where.endswith(".scores"):
        # stored as float16 (documented): that rounding, and the same strongest-first order
        assert isinstance(b, np.ndarray) and b.shape == a.shape and b.dtype == np.float32, where
        np.testing.assert_array_equal(b, a.astype(np.float16).astype(np.float32), err_msg=where)
    elif isinstance(a, np.ndarray) and where.endswith(".depth"):
        # keypoint depth is stored as float16 metres, 0 = none (documented): that rounding, NaN kept
        assert isinstance(b, np.ndarray) and b.shape == a.shape and b.dtype == np.float32, where
        np.testing.assert_array_equal(np.isnan(b), ~(np.isfinite(a) & (a > 0)), err_msg=where)
        ok = ~np.isnan(b)
        np.testing.assert_array_equal(b[ok], a[ok].astype(np.float16).astype(np.float32), err_msg=where)
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


def test_loaded_features_and_images_are_lazy_and_exact(saved_map: Path, tmp_path: Path) -> None:
    from litevloc.pipelines.topomap.map_save import map_arrays
    from litevloc.pipelines.topomap.types import FeatureStore, keypoints_from_fixed

    m = load_map(saved_map)
    assert isinstance(m.features, FeatureStore)
    assert isinstance(m.features.descriptors, np.memmap)  # stays on disk
    arrays = map_arrays(m)
    off = arrays["features/offsets.npy"]
    for i in (0, m.n_nodes - 1):
        f = m.features[i]
        a, b = off[i], off[i + 1]
        stored = arrays["features/descriptors.npy"][a:b]
        assert f.descriptors.dtype == (np.float32 if stored.dtype == np.float16 else stored.dtype)
        assert np.array_equal(f.descriptors, stored.astype(f.descriptors.dtype))
        assert np.array_equal(f.keypoints, keypoints_from_fixed(arrays["features/keypoints.npy"][a:b]))
        assert np.array_equal(f.scores, arrays["features/scores.npy"][a:b].astype(np.float32))
    assert np.array_equal(m.features[-1].descriptors, m.features[m.n_nodes - 1].descriptors)
    assert len(list(m.features)) == m.n_nodes and len(m.features[1:3]) == 2
    with pytest.raises(IndexError):
        m.features[m.n_nodes]
    # saving a loaded map gives the same bytes (the FeatureStore path of map_arrays), except
    # the VPR scales: the loader renormalises the dequantised descriptors
    again = save_map(m, tmp_path / "again")
    a, b = (json.loads((p / "manifest.json").read_text())["files"] for p in (again, saved_map))
    assert {k: v for k, v in a.items() if k != "vpr/scale.npy"} == {k: v for k, v in b.items() if k != "vpr/scale.npy"}
    # images are re-read and re-checked on access: a file changed after loading is named
    d = copy(saved_map, tmp_path / "c")
    m2 = load_map(d)
    assert m2.images_jpeg[0] == m.images_jpeg[0] and m2.images_jpeg[0][:2] == b"\xff\xd8"
    p = d / "images/000000.jpg"
    data = bytearray(p.read_bytes())
    data[100] ^= 0x01
    p.write_bytes(bytes(data))
    with pytest.raises(MapFormatError, match=r"images/000000\.jpg: checksum mismatch"):
        m2.images_jpeg[0]


def as_v1(d: Path, m: TopoMap) -> None:
    """Keypoints and scores of map `d` (loaded as `m`) rewritten as versions 1-2 stored them: float32."""
    store = m.features
    _replace_array(d, "features/keypoints.npy", np.concatenate([f.keypoints for f in store]).astype(np.float32))
    _replace_array(d, "features/scores.npy", np.asarray(store.scores, np.float32))  # type: ignore[attr-defined]


def test_streamed_feature_files_are_fully_checked(saved_map: Path, tmp_path: Path) -> None:
    m = load_map(saved_map)
    M = len(m.features.descriptors)  # type: ignore[attr-defined]
    desc = np.random.default_rng(0).normal(size=(M, 8)).astype(np.float16)
    d0 = copy(saved_map, tmp_path / "f")
    _replace_array(d0, "features/descriptors.npy", desc)
    with pytest.raises(MapFormatError, match=r"features/descriptors\.npy: dtype float16, expected int8"):
        load_map(d0)  # version 2 stores float descriptors as int8 codes
    rewrite_manifest(d0, lambda man: man.__setitem__("version", 1))
    with pytest.raises(MapFormatError, match=r"features/keypoints\.npy: dtype uint16, expected float32"):
        load_map(d0)  # fixed-point keypoints are format 3's
    as_v1(d0, m)
    f0 = load_map(d0).features[1]  # a version-1 map: float16 on disk, float32 per node on access
    assert f0.descriptors.dtype == np.float32 and f0.descriptors.shape[1] == 8
    # version 2: int8 codes and one float32 scale per row, float32 per node on access
    codes = np.random.default_rng(1).integers(-127, 128, size=(M, 8)).astype(np.int8)
    scale = np.linspace(0.001, 0.01, M).astype(np.float32)
    dq = copy(saved_map, tmp_path / "q")
    _replace_array(dq, "features/descriptors.npy", codes)
    with pytest.raises(MapFormatError, match=r"features/descriptor_scale\.npy: not listed"):
        load_map(dq)
    _replace_array(dq, "features/descriptor_scale.npy", scale)
    fq = load_map(dq).features
    lo, hi = fq.offsets[1], fq.offsets[2]  # type: ignore[attr-defined]
    np.testing.assert_array_equal(fq[1].descriptors, codes[lo:hi].astype(np.float32) * scale[lo:hi, None])
    scale[-1] = 0.0  # the last row: the streaming check reads to the end
    _replace_array(dq, "features/descriptor_scale.npy", scale)
    with pytest.raises(MapFormatError, match=r"features/descriptor_scale\.npy: scales must be > 0"):
        load_map(dq)
    dz = copy(saved_map, tmp_path / "z")
    z = np.asarray(m.features.depth).copy()  # type: ignore[attr-defined]
    z[-1] = -1.0
    _replace_array(dz, "features/depth.npy", z)
    with pytest.raises(MapFormatError, match=r"features/depth\.npy: depths must be >= 0"):
        load_map(dz)
    desc[-1, -1] = np.inf  # the last value of the largest file: the streaming check reads to the end
    d = copy(saved_map, tmp_path / "a")
    _replace_array(d, "features/descriptors.npy", desc)
    rewrite_manifest(d, lambda man: man.__setitem__("version", 1))
    as_v1(d, m)
    with pytest.raises(MapFormatError, match=r"features/descriptors\.npy: contains NaN"):
        load_map(d)
    d2 = copy(saved_map, tmp_path / "b")
    p = d2 / "features/descriptors.npy"
    data = bytearray(p.read_bytes())
    data[len(data) // 2] ^= 0x10
    p.write_bytes(bytes(data))
    with pytest.raises(MapFormatError, match=r"features/descriptors\.npy: checksum mismatch"):
        load_map(d2)
    d3 = copy(saved_map, tmp_path / "c")
    _replace_array(d3, "features/scores.npy", np.asarray(m.features.scores[:-1]))  # type: ignore[attr-defined]
    with pytest.raises(MapFormatError, match=r"features/scores\.npy: shape"):
        load_map(d3)
    d4 = copy(saved_map, tmp_path / "d")
    kps = np.asarray(m.features.keypoints).copy()  # type: ignore[attr-defined]
    kps[-1, 0] = 65000  # 8124.5 px
    _replace_array(d4, "features/keypoints.npy", kps)
    with pytest.raises(MapFormatError, match=f"keypoints of node {m.n_nodes - 1} fall outside"):
        load_map(d4)
    d5 = copy(saved_map, tmp_path / "e")
    _replace_array(d5, "features/descriptors.npy", np.array([{"a": 1}], dtype=object))
    with pytest.raises(MapFormatError, match=r"features/descriptors\.npy: dtype object"):
        load_map(d5)


def test_non_rigid_pose_is_named(saved_map: Path, tmp_path: Path) -> None:
    m = load_map(saved_map)
    T = m.T_map_camera.copy()
    T[2, :3, :3] *= 1.01
    d = copy(saved_map, tmp_path)
    _replace_array(d, "nodes/T_map_camera.npy", T)
    with pytest.raises(MapFormatError, match="pose of node 2 is not a rigid"):
        load_map(d)


def test_int8_descriptors_keep_nearest_neighbours() -> None:
    # 128-d unit descriptors like ALIKED's, queries noisy enough that the best match's cosine
    # is ~0.8 (a typical accepted LightGlue pair): the stored codes change no nearest neighbour
    # in 99 % of queries and no similarity by more than 0.01
    from litevloc.pipelines.topomap.map_save import quantise

    rng = np.random.default_rng(0)
    ref = rng.normal(size=(2048, 128)).astype(np.float32)
    ref /= np.linalg.norm(ref, axis=1, keepdims=True)
    q = ref[:512] + rng.normal(scale=0.06, size=(512, 128)).astype(np.float32)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    codes, scale = quantise(ref)
    deq = codes.astype(np.float32) * scale[:, None]
    s32, s8 = q @ ref.T, q @ deq.T
    assert 0.7 < float(np.median(s32.max(axis=1))) < 0.9
    assert np.mean(s32.argmax(axis=1) == s8.argmax(axis=1)) >= 0.99
    assert float(np.abs(s32 - s8).max()) < 0.01
    assert codes.nbytes + scale.nbytes < 0.52 * ref.astype(np.float16).nbytes


def float_feature_map(m: TopoMap, dim: int = 128) -> TopoMap:
    """The map with float unit descriptors (clustered, like learned ones) instead of ORB's bits."""
    from litevloc.pipelines.topomap.types import NodeFeatures

    from .test_descriptor_codec import clustered_descriptors

    feats = []
    for i, f in enumerate(m.features):
        d = clustered_descriptors(len(f.keypoints), dim, seed=i)
        feats.append(NodeFeatures(f.keypoints, d, f.scores, f.image_size, getattr(f, "depth", None)))
    return dataclasses.replace(m, features=feats)


def test_product_quantised_descriptors_round_trip(built_map: TopoMap, tmp_path: Path) -> None:
    from litevloc.pipelines.topomap.descriptor_codec import decode, encode

    m = float_feature_map(built_map)
    saved = save_map(m, tmp_path / "pq")  # the default: 32 bytes per descriptor
    man = json.loads((saved / "manifest.json").read_text())
    assert man["version"] == 3 and man["descriptor_codec"] == "pq"
    loaded = load_map(saved)
    book = loaded.features.codebook  # type: ignore[attr-defined]
    assert book.shape == (32, 256, 4) and loaded.features.descriptors.shape[1] == 32  # type: ignore[attr-defined]
    for i in (0, m.n_nodes - 1):
        a = np.asarray(m.features[i].descriptors)
        b = loaded.features[i].descriptors
        assert b.dtype == np.float32 and b.shape == a.shape
        np.testing.assert_array_equal(b, decode(encode(a, book), book))  # exactly the codec's rounding
        assert float(np.median(np.sum(a * b, axis=1))) > 0.95
    # re-saving a loaded map keeps its codes and codebook byte for byte; other encodings re-encode
    again = json.loads((save_map(loaded, tmp_path / "again") / "manifest.json").read_text())["files"]
    for rel in ("features/descriptors.npy", "features/descriptor_codebook.npy", "features/keypoints.npy"):
        assert again[rel] == man["files"][rel]
    as_int8 = load_map(save_map(loaded, tmp_path / "int8", descriptor_bytes=0))
    assert as_int8.features.codebook is None and as_int8.features.descriptor_scale is not None  # type: ignore[attr-defined]
    np.testing.assert_allclose(as_int8.features[1].descriptors, loaded.features[1].descriptors, atol=0.01)
    # a quarter of the int8 encoding's bytes (132 per 128-d descriptor)
    files = man["files"]
    pq_bytes = files["features/descriptors.npy"]["bytes"] + files["features/descriptor_codebook.npy"]["bytes"]
    int8_files = json.loads((tmp_path / "int8" / "manifest.json").read_text())["files"]
    int8_bytes = int8_files["features/descriptors.npy"]["bytes"] + int8_files["features/descriptor_scale.npy"]["bytes"]
    n = len(loaded.features.descriptors)  # type: ignore[attr-defined]
    assert int8_bytes >= 132 * n and pq_bytes <= 32 * n + 32 * 256 * 4 * 4 + 256
    with pytest.raises(MapFormatError, match=r"descriptor_bytes: .*divisible"):
        save_map(m, tmp_path / "bad", descriptor_bytes=48)
    # no fewer bytes than dimensions: int8 codes (a quantiser could not be smaller)
    small = save_map(float_feature_map(built_map, dim=16), tmp_path / "small", descriptor_bytes=32)
    assert json.loads((small / "manifest.json").read_text())["descriptor_codec"] == "int8"


def test_product_quantiser_problems_are_named(built_map: TopoMap, tmp_path: Path) -> None:
    saved = save_map(float_feature_map(built_map, dim=16), tmp_path / "pq", descriptor_bytes=4)
    codes = np.asarray(load_map(saved).features.descriptors).copy()  # type: ignore[attr-defined]
    d = copy(saved, tmp_path / "a")
    book = np.load(d / "features/descriptor_codebook.npy")
    _replace_array(d, "features/descriptor_codebook.npy", book[:, :100].copy())
    codes[-1, 2] = 200  # the last row: the streaming check reads to the end
    _replace_array(d, "features/descriptors.npy", codes)
    with pytest.raises(MapFormatError, match=r"features/descriptors\.npy: codes must be < 100"):
        load_map(d)
    d = copy(saved, tmp_path / "b")
    rewrite_manifest(d, lambda man: man["files"].pop("features/descriptor_codebook.npy"))
    with pytest.raises(MapFormatError, match=r"descriptor_codebook\.npy: not listed"):
        load_map(d)
    d = copy(saved, tmp_path / "c")
    rewrite_manifest(d, lambda man: man.__setitem__("descriptor_codec", "zip"))
    with pytest.raises(MapFormatError, match="'descriptor_codec' must be one of"):
        load_map(d)
    d = copy(saved, tmp_path / "d")
    rewrite_manifest(d, lambda man: man.__setitem__("version", 2))
    with pytest.raises(MapFormatError, match="needs map version 3"):
        load_map(d)
    d = copy(saved, tmp_path / "e")
    _replace_array(d, "features/descriptor_codebook.npy", np.zeros((4, 300, 4), np.float32))
    with pytest.raises(MapFormatError, match=r"descriptor_codebook\.npy: shape \(4, 300, 4\)"):
        load_map(d)
    d = copy(saved, tmp_path / "f")
    _replace_array(d, "features/descriptors.npy", codes[:, :3].copy())
    with pytest.raises(MapFormatError, match=r"features/descriptors\.npy: shape"):
        load_map(d)
    d = copy(saved, tmp_path / "g")
    book[0, 0, 0] = np.nan
    _replace_array(d, "features/descriptor_codebook.npy", book)
    with pytest.raises(MapFormatError, match=r"descriptor_codebook\.npy: contains NaN"):
        load_map(d)


def test_keypoints_beyond_the_fixed_point_range_stay_float() -> None:
    from litevloc.pipelines.topomap.map_save import stored_keypoints
    from litevloc.pipelines.topomap.types import KEYPOINT_FIXED_MAX, keypoints_from_fixed, keypoints_to_fixed

    k = np.array([[-0.5, 0.0], [100.3, 7.06], [KEYPOINT_FIXED_MAX, 2.0]], np.float32)
    q = stored_keypoints(k)
    assert q.dtype == np.uint16
    assert float(np.abs(keypoints_from_fixed(q) - k).max()) <= 1 / 16
    big = np.array([[9000.0, 1.0]], np.float32)  # a > 8191 px image: float32, as format 2 stored them
    assert stored_keypoints(big).dtype == np.float32
    with pytest.raises(ValueError, match="fixed-point"):
        keypoints_to_fixed(big)
