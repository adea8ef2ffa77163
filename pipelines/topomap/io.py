"""On-disk map format (version 3; versions 1 and 2 still load) and its validating loader.

A map is a folder:

```
manifest.json                 format, version, counts, model names, sha256 + size per file
nodes/T_map_camera.npy        (N,4,4) float64     nodes/K.npy            (N,3,3) float64
nodes/image_size.npy          (N,2) int32 (w,h)   nodes/t_ns.npy         (N,) int64
nodes/frame_index.npy         (N,) int64          vpr/descriptors.npy    (N,D) int8, vpr/scale.npy (N,) float32
features/offsets.npy          (N+1,) int64: node i owns rows offsets[i]:offsets[i+1]
features/keypoints.npy        (M,2) uint16: 1/8 px steps from -0.5 px (version 3; float32 pixels in
                              version 1-2, or beyond 8191 px)
features/scores.npy           (M,) float16 (version 3; float32 in version 1-2)
features/descriptors.npy      float descriptors: (M,S) uint8 product-quantiser codes (manifest
                              descriptor_codec "pq", version 3) or (M,Df) int8 codes ("int8",
                              version 2-3; version 1: float16); binary descriptors: (M,Df) uint8
features/descriptor_codebook.npy (S,K,Df/S) float32, K <= 256: the codes' centroids ("pq")
features/descriptor_scale.npy (M,) float32 > 0: row scale of int8 codes ("int8")
features/depth.npy            (M,) float16 >= 0: mapping depth at each keypoint, metres, 0 = none
                              (version 2, optional: maps without it still load)
graph/covisibility_edges.npy  (E,2) int64 i<j     graph/covisibility_inliers.npy (E,) int32
graph/covisibility_weight.npy (E,) float32 (0,1]  graph/connectivity_edges.npy   (F,2) int64 i<j
graph/connectivity_metres.npy (F,) float32 >= 0
grid/cells.npy                (H,W) uint8 {0 unknown, 1 free, 2 occupied}
grid/frame.npy                (12,) float64: origin(2), resolution, up(3), plane axes(6)
images/NNNNNN.jpg             keyframe images (JPEG), one per node
```

Local float descriptors are most of a map's bytes. By default (`mapping.descriptor_bytes`
32) they are product-quantised (`descriptor_codec.py`): 32 one-byte centroid indices per
128-d ALIKED descriptor with a codebook trained on the map, 4x smaller than int8 codes with
one float32 scale per keypoint (132 bytes, format 2, `descriptor_bytes` 0), which were 52 %
of float16's 256 (format 1). Decoded descriptors are unit vectors with a median cosine of
0.96 to the originals; on the 7-Scenes mapping-pass splits localization within [5 cm, 5 deg]
went 24.8 / 38.4 % -> 24.0 / 36.0 %. Place descriptors are int8 codes with one scale per
node (1280-d EfficientNet-GeM costs 1.3 KB per node); cosine similarities change by < 2e-3,
far below the margins that rank places (`tests/pipelines/topomap/test_io.py`).
The loader returns float32 (place descriptors as unit vectors).
Plain `.npy` files (never pickle; loaded with `allow_pickle=False`) so building twice
gives byte-identical files. `load_map` checks everything and raises `MapFormatError`
naming the file and the problem: missing, unlisted, truncated (size), checksum, wrong
dtype/shape, non-finite values, non-rigid poses, out-of-range edges, wrong version.
"""

from __future__ import annotations

import hashlib
import io
import json
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, cast, overload

import numpy as np
from numpy.typing import NDArray

from litevloc.base.errors import LiteVLocError
from litevloc.pipelines.topomap.descriptor_codec import MAX_CENTROIDS
from litevloc.pipelines.topomap.npy_scan import RowCheck, scan_npy
from litevloc.pipelines.topomap.types import FeatureStore, OccupancyGrid, TopoMap, keypoints_from_fixed

FORMAT = "litevloc-map"
VERSION = 3
READABLE_VERSIONS = (1, 2, 3)
MANIFEST = "manifest.json"


class MapFormatError(LiteVLocError, ValueError):
    """A map folder is missing, corrupt or inconsistent; the message names the file."""


def sha256_hex(data: bytes) -> str:
    """The SHA-256 of `data` as the manifest lists it (hex)."""
    return hashlib.sha256(data).hexdigest()


def _fail(folder: Path, rel: str, problem: str) -> MapFormatError:
    return MapFormatError(f"map {folder}: {rel}: {problem}")


def read_manifest(folder: Path) -> dict[str, Any]:
    if not folder.is_dir():
        raise MapFormatError(f"map folder not found: {folder}")
    mpath = folder / MANIFEST
    if not mpath.is_file():
        raise _fail(folder, MANIFEST, "missing (not a LiteVLoc map folder?)")
    try:
        man = json.loads(mpath.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise _fail(folder, MANIFEST, f"not valid JSON ({exc})") from exc
    if not isinstance(man, dict) or man.get("format") != FORMAT:
        raise _fail(folder, MANIFEST, f"format must be {FORMAT!r}")
    if man.get("version") not in READABLE_VERSIONS:
        raise _fail(folder, MANIFEST, f"unsupported map version {man.get('version')!r} (this build reads "
                    f"{', '.join(map(str, READABLE_VERSIONS))})")
    files = man.get("files")
    if not isinstance(files, dict):
        raise _fail(folder, MANIFEST, "'files' must be a mapping of path -> {sha256, bytes}")
    n = man.get("nodes")
    if not isinstance(n, int) or n < 1:
        raise _fail(folder, MANIFEST, f"'nodes' must be a positive integer, got {n!r}")
    return man


def _check_entry(folder: Path, rel: str, entry: Any) -> Path:
    if ".." in Path(rel).parts or Path(rel).is_absolute():
        raise _fail(folder, rel, "path escapes the map folder")
    p = folder / rel
    if not p.is_file():
        raise _fail(folder, rel, "missing")
    well_formed = (
        isinstance(entry, dict) and isinstance(entry.get("sha256"), str) and isinstance(entry.get("bytes"), int)
    )
    if not well_formed:
        raise _fail(folder, MANIFEST, f"entry for {rel} must have sha256 and bytes")
    return p


def _read_verified(folder: Path, rel: str, entry: Any) -> bytes:
    p = _check_entry(folder, rel, entry)
    data = p.read_bytes()
    if len(data) != entry["bytes"]:
        raise _fail(folder, rel, f"truncated or extended: {len(data)} bytes, manifest says {entry['bytes']}")
    if sha256_hex(data) != entry["sha256"]:
        raise _fail(folder, rel, "checksum mismatch (file modified or corrupt)")
    return data


def _check_jpeg(folder: Path, rel: str, data: bytes) -> None:
    if data[:2] != b"\xff\xd8" or b"\xff\xd9" not in data[-16:]:
        raise _fail(folder, rel, "not a complete JPEG")


class VerifiedImages(Sequence[bytes]):
    """Keyframe JPEGs of a loaded map, read on access (not held in memory).

    Every image was read, checksummed and checked at load time; each access reads the
    file again and repeats the size, sha256 and JPEG checks (a file changed since loading
    is an error naming it, never silently different data)."""

    def __init__(self, folder: Path, entries: list[Any]) -> None:
        self.folder, self.entries = folder, entries

    def __len__(self) -> int:
        return len(self.entries)

    def _get(self, i: int) -> bytes:
        n = len(self)
        if i < 0:
            i += n
        if not 0 <= i < n:
            raise IndexError(f"image {i} not in 0..{n - 1}")
        rel = f"images/{i:06d}.jpg"
        data = _read_verified(self.folder, rel, self.entries[i])
        _check_jpeg(self.folder, rel, data)
        return data

    @overload
    def __getitem__(self, i: int) -> bytes: ...

    @overload
    def __getitem__(self, i: slice) -> list[bytes]: ...

    def __getitem__(self, i: int | slice) -> bytes | list[bytes]:
        if isinstance(i, slice):
            return [self._get(k) for k in range(*i.indices(len(self)))]
        return self._get(int(i))


def _check_layout(folder: Path, rel: str, a_dtype: np.dtype[Any], a_shape: tuple[int, ...], dtype: Any,
                  shape: tuple[int | None, ...]) -> None:
    """An array's dtype is one of `dtype` (one or a tuple) and its shape matches `shape`
    (None = any length)."""
    dtypes = dtype if isinstance(dtype, tuple) else (dtype,)
    if a_dtype not in [np.dtype(d) for d in dtypes]:
        raise _fail(folder, rel, f"dtype {a_dtype}, expected {' or '.join(str(np.dtype(d)) for d in dtypes)}")
    if len(a_shape) != len(shape) or any(s is not None and s != d for s, d in zip(shape, a_shape, strict=True)):
        want = "x".join("*" if s is None else str(s) for s in shape)
        raise _fail(folder, rel, f"shape {a_shape}, expected {want}")


def _streamed_npy(
    folder: Path, rel: str, entry: Any, dtype: Any, shape: tuple[int | None, ...], row_check: RowCheck | None = None,
) -> NDArray[Any]:
    """A large .npy verified in one streaming pass (`npy_scan`), then opened as a read-only
    memory map: the map's pages are read on use, checking costs no memory. Same checks and
    messages as `_array` on `_read_verified` bytes, in the same order (size, checksum,
    readable header, dtype, shape, values)."""
    p = _check_entry(folder, rel, entry)
    size = p.stat().st_size
    if size != entry["bytes"]:
        raise _fail(folder, rel, f"truncated or extended: {size} bytes, manifest says {entry['bytes']}")
    scan = scan_npy(p, size, dtype if isinstance(dtype, tuple) else (dtype,), len(shape), row_check)
    if scan.sha256 != entry["sha256"]:
        raise _fail(folder, rel, "checksum mismatch (file modified or corrupt)")
    if scan.header is None:
        raise _fail(folder, rel, f"not a readable .npy array ({scan.header_error})")
    a_shape, _fortran, a_dtype = scan.header
    _check_layout(folder, rel, np.dtype(a_dtype), a_shape, dtype, shape)
    if scan.problem is not None:
        raise _fail(folder, rel, scan.problem)
    try:
        a = cast(NDArray[Any], np.load(p, mmap_mode="r", allow_pickle=False))  # a .npy file: an ndarray (memmap)
    except (ValueError, OSError, EOFError) as exc:
        raise _fail(folder, rel, f"not a readable .npy array ({exc})") from exc
    if a.shape != tuple(a_shape) or a.dtype != np.dtype(a_dtype):
        raise _fail(folder, rel, "changed while loading")
    return a


def _array(folder: Path, rel: str, data: bytes, dtype: Any, shape: tuple[int | None, ...]) -> NDArray[Any]:
    try:
        a: NDArray[Any] = np.load(io.BytesIO(data), allow_pickle=False)  # .npy bytes: an ndarray
    except (ValueError, OSError, EOFError) as exc:
        raise _fail(folder, rel, f"not a readable .npy array ({exc})") from exc
    _check_layout(folder, rel, a.dtype, a.shape, dtype, shape)
    if a.dtype.kind == "f" and not np.all(np.isfinite(a)):
        raise _fail(folder, rel, "contains NaN or infinity")
    return a


def _rigid_rows(T: NDArray[np.float64], atol: float) -> NDArray[np.bool_]:
    """Per pose of (N, 4, 4) finite T: `geometry.is_rigid` as one array operation."""
    R = T[:, :3, :3]
    eye = np.eye(3)
    RRt = R @ np.swapaxes(R, 1, 2)
    orth = np.all(np.abs(RRt - eye) <= atol + 1e-5 * eye, axis=(1, 2))
    det = np.abs(np.linalg.det(R) - 1.0) < atol * 10 if len(T) else np.zeros(0, bool)
    last = np.all(np.abs(T[:, 3] - [0, 0, 0, 1]) <= atol + 1e-5 * np.array([0, 0, 0, 1]), axis=1)
    return np.asarray(orth & det & last)


# Files streamed instead of read whole (they grow with keypoints x nodes); the descriptors
# stay on disk as a read-only memory map.
_STREAMED = {"features/keypoints.npy", "features/scores.npy", "features/descriptors.npy"}


def _positive_scales(a: NDArray[Any], first: int) -> str | None:
    if a.size and not bool(a.min() > 0):
        return f"scales must be > 0 (row {first + int(np.argmin(a))})"
    return None


def _nonnegative_depths(a: NDArray[Any], first: int) -> str | None:
    if a.size and not bool(a.min() >= 0):
        return f"depths must be >= 0 (row {first + int(np.argmin(a))})"
    return None


_CODECS = ("pq", "int8", "binary")


def _codebook(root: Path, man: dict[str, Any]) -> NDArray[np.float32] | None:
    """The product quantiser's (S, K, d) codebook of a format-3 map whose manifest says
    `descriptor_codec: pq` (checked: listed, size, checksum, dtype, shape, 1 <= K <= 256,
    finite), else None."""
    rel = "features/descriptor_codebook.npy"
    files: dict[str, Any] = man["files"]
    codec = man.get("descriptor_codec", "int8" if man["version"] < 3 else None)
    if codec not in _CODECS:
        raise _fail(root, MANIFEST, f"'descriptor_codec' must be one of {', '.join(_CODECS)}, got {codec!r}")
    if codec != "pq":
        if rel in files:
            raise _fail(root, rel, f"listed, but the manifest's descriptor_codec is {codec!r}")
        return None
    if man["version"] < 3:
        raise _fail(root, MANIFEST, "descriptor_codec 'pq' needs map version 3")
    if rel not in files:
        raise _fail(root, rel, "not listed in manifest.json (product-quantiser codes need their codebook)")
    book = _array(root, rel, _read_verified(root, rel, files[rel]), np.float32, (None, None, None))
    if not (book.shape[0] >= 1 and 1 <= book.shape[1] <= MAX_CENTROIDS and book.shape[2] >= 1):
        raise _fail(root, rel, f"shape {book.shape}, expected (S >= 1, 1 <= K <= {MAX_CENTROIDS}, d >= 1)")
    return book


def _codes_below(k: int) -> RowCheck:
    def check(a: NDArray[Any], first: int) -> str | None:
        if a.size and int(a.max()) >= k:
            return f"codes must be < {k}, the codebook's size (row {first + int(np.argmax(a.max(axis=1)))})"
        return None
    return check


def _load_features(root: Path, man: dict[str, Any], off: NDArray[np.int64], size: NDArray[np.int32]) -> FeatureStore:
    """The local features of a map folder (`off` (N+1,) row offsets, `size` (N, 2) image sizes),
    each file checked in one streaming pass and memory-mapped (see `load_map`)."""
    files: dict[str, Any] = man["files"]
    N = len(size)
    M = int(off[-1])
    if off[0] != 0 or np.any(np.diff(off) < 0):
        raise _fail(root, "features/offsets.npy", "must rise from 0 (node i owns rows offsets[i]:offsets[i+1])")
    wh = size.astype(np.float32) - 0.5

    def in_image(k: NDArray[Any], first: int) -> str | None:
        """Keypoints of rows first.. lie inside their node's image (one array operation)."""
        if k.dtype == np.uint16:
            k = keypoints_from_fixed(k)
        # rows past offsets[-1] (a count mismatch, reported after the pass) count as the last node's
        owner = np.minimum(np.searchsorted(off, np.arange(first, first + len(k)), side="right") - 1, N - 1)
        out = (k.min(axis=1) < -0.5) | (k[:, 0] > wh[owner, 0]) | (k[:, 1] > wh[owner, 1])
        if out.any():
            i = int(owner[int(np.argmax(out))])
            return f"keypoints of node {i} fall outside its {int(size[i, 0])}x{int(size[i, 1])} image"
        return None

    v3 = man["version"] >= 3  # fixed-point keypoints and float16 scores
    codebook = _codebook(root, man)  # the manifest's codec first: it decides what the features must be
    kps = _streamed_npy(root, "features/keypoints.npy", files["features/keypoints.npy"],
                        (np.float32, np.uint16) if v3 else np.float32, (None, 2), in_image if N else None)
    if len(kps) != M:
        raise _fail(root, "features/offsets.npy", f"must rise from 0 to {len(kps)} (keypoint count)")
    scores = _streamed_npy(root, "features/scores.npy", files["features/scores.npy"],
                           (np.float32, np.float16) if v3 else np.float32, (M,))
    v1 = man["version"] == 1
    desc = _streamed_npy(root, "features/descriptors.npy", files["features/descriptors.npy"],
                         (np.float16, np.uint8) if v1 else (np.int8, np.uint8),
                         (M, None if codebook is None else codebook.shape[0]),
                         None if codebook is None else _codes_below(len(codebook[0])))
    if codebook is not None and desc.dtype != np.uint8:
        raise _fail(root, "features/descriptors.npy", f"dtype {desc.dtype}, expected uint8 (product-quantiser codes)")
    desc_scale = None
    if desc.dtype == np.int8:
        rel = "features/descriptor_scale.npy"
        if rel not in files:
            raise _fail(root, rel, "not listed in manifest.json (int8 descriptors need their row scales)")
        desc_scale = _streamed_npy(root, rel, files[rel], np.float32, (M,), _positive_scales)
    depth = None
    if "features/depth.npy" in files:
        rel = "features/depth.npy"
        depth = _streamed_npy(root, rel, files[rel], np.float16, (M,), _nonnegative_depths)
    return FeatureStore(off, kps, desc, scores, size, descriptor_scale=desc_scale, depth=depth, codebook=codebook)


_REQUIRED = (
    "nodes/T_map_camera.npy", "nodes/K.npy", "nodes/image_size.npy", "nodes/t_ns.npy", "nodes/frame_index.npy",
    "vpr/descriptors.npy", "vpr/scale.npy", "features/offsets.npy", "features/keypoints.npy", "features/scores.npy",
    "features/descriptors.npy", "graph/covisibility_edges.npy", "graph/covisibility_inliers.npy",
    "graph/covisibility_weight.npy", "graph/connectivity_edges.npy", "graph/connectivity_metres.npy",
    "grid/cells.npy", "grid/frame.npy",
)

ArrayOf = Callable[[str, Any, tuple[int | None, ...]], NDArray[Any]]  # (file, dtype(s), shape) -> checked array


def _nodes(arr: ArrayOf, root: Path, N: int) -> tuple[NDArray[Any], ...]:
    """The (N, ...) node arrays: T_map_camera (rigid), K (positive focal lengths), image_size
    (positive), t_ns, frame_index."""
    T = arr("nodes/T_map_camera.npy", np.float64, (N, 4, 4))
    bad = np.flatnonzero(~_rigid_rows(T, atol=1e-5))
    if len(bad):
        raise _fail(root, "nodes/T_map_camera.npy", f"pose of node {int(bad[0])} is not a rigid transform")
    K = arr("nodes/K.npy", np.float64, (N, 3, 3))
    if np.any(K[:, 0, 0] <= 0) or np.any(K[:, 1, 1] <= 0):
        raise _fail(root, "nodes/K.npy", "focal lengths must be positive")
    size = arr("nodes/image_size.npy", np.int32, (N, 2))
    if np.any(size <= 0):
        raise _fail(root, "nodes/image_size.npy", "image sizes must be positive")
    return T, K, size, arr("nodes/t_ns.npy", np.int64, (N,)), arr("nodes/frame_index.npy", np.int64, (N,))


def _place_descriptors(arr: ArrayOf, root: Path, N: int, vpr_dim: Any) -> NDArray[np.float32]:
    """(N, D) float32 unit place descriptors decoded from their int8 codes and row scales;
    D must be the manifest's `vpr_dim`."""
    codes = arr("vpr/descriptors.npy", np.int8, (N, None))
    vpr_scale = arr("vpr/scale.npy", np.float32, (N,))
    vpr = codes.astype(np.float32)
    vpr *= vpr_scale[:, None]
    norms = np.linalg.norm(vpr, axis=1, keepdims=True)
    if np.any(norms < 1e-6):
        raise _fail(root, "vpr/descriptors.npy", "a descriptor is zero")
    vpr /= norms
    if vpr.shape[1] != vpr_dim:
        raise _fail(root, "vpr/descriptors.npy", f"dimension {vpr.shape[1]} != manifest vpr_dim {vpr_dim}")
    return vpr


def _graphs(arr: ArrayOf, root: Path, N: int) -> tuple[NDArray[Any], ...]:
    """Covisibility (E,2) edges, (E,) inliers, (E,) weights in (0, 1] and connectivity (F,2)
    edges, (F,) metres >= 0; every edge a node pair i < j."""
    ce = arr("graph/covisibility_edges.npy", np.int64, (None, 2))
    ci = arr("graph/covisibility_inliers.npy", np.int32, (len(ce),))
    cw = arr("graph/covisibility_weight.npy", np.float32, (len(ce),))
    ne = arr("graph/connectivity_edges.npy", np.int64, (None, 2))
    nm = arr("graph/connectivity_metres.npy", np.float32, (len(ne),))
    for rel, e in (("graph/covisibility_edges.npy", ce), ("graph/connectivity_edges.npy", ne)):
        if len(e) and (e.min() < 0 or e.max() >= N or np.any(e[:, 0] >= e[:, 1])):
            raise _fail(root, rel, f"edges must be node pairs i < j within 0..{N - 1}")
    if len(cw) and (cw.min() <= 0 or cw.max() > 1):
        raise _fail(root, "graph/covisibility_weight.npy", "weights must be in (0, 1]")
    if len(nm) and nm.min() < 0:
        raise _fail(root, "graph/connectivity_metres.npy", "lengths must be >= 0")
    return ce, ci, cw, ne, nm


def _grid(arr: ArrayOf, root: Path) -> OccupancyGrid:
    """The occupancy grid: cells in {0, 1, 2} and its frame (positive resolution)."""
    cells = arr("grid/cells.npy", np.uint8, (None, None))
    if cells.size and cells.max() > 2:
        raise _fail(root, "grid/cells.npy", "cell values must be 0, 1 or 2")
    gf = arr("grid/frame.npy", np.float64, (12,))
    if gf[2] <= 0:
        raise _fail(root, "grid/frame.npy", "resolution must be positive")
    return OccupancyGrid(cells, gf[0:2].copy(), float(gf[2]), gf[3:6].copy(), gf[6:12].reshape(2, 3).copy())


def load_map(folder: str | Path) -> TopoMap:
    """Load and validate a map folder (see module docstring); MapFormatError on any problem.

    Every file listed is checked (size, sha256, dtype, shape, values) before the map is
    returned. Keyframe images are not kept in memory (`VerifiedImages` re-reads and
    re-checks one on access) and the local features (keypoints, scores, descriptors) are
    checked in one streaming pass each and then memory-mapped read-only (`FeatureStore`
    gives one node's features, descriptors as float32, on access), so memory grows with
    the node count by the VPR descriptors (N x D float32) and the small node arrays only."""
    root = Path(folder)
    man = read_manifest(root)
    files: dict[str, Any] = man["files"]
    N = int(man["nodes"])
    image_rels = [f"images/{i:06d}.jpg" for i in range(N)]
    for rel in [*_REQUIRED, *image_rels]:
        if rel not in files:
            raise _fail(root, rel, "not listed in manifest.json")
    raw = {rel: _read_verified(root, rel, files[rel]) for rel in _REQUIRED if rel not in _STREAMED}

    def arr(rel: str, dtype: Any, shape: tuple[int | None, ...]) -> NDArray[Any]:
        return _array(root, rel, raw[rel], dtype, shape)

    T, K, size, t_ns, frame_index = _nodes(arr, root, N)
    vpr = _place_descriptors(arr, root, N, man.get("vpr_dim"))
    feats = _load_features(root, man, arr("features/offsets.npy", np.int64, (N + 1,)), size)
    ce, ci, cw, ne, nm = _graphs(arr, root, N)
    grid = _grid(arr, root)
    for rel in image_rels:  # every image checked now, none kept
        _check_jpeg(root, rel, _read_verified(root, rel, files[rel]))
    images = VerifiedImages(root, [files[rel] for rel in image_rels])
    meta = man.get("meta", {})
    return TopoMap(
        T_map_camera=T, K=K, image_size=size, t_ns=t_ns, frame_index=frame_index, vpr=vpr, features=feats,
        images_jpeg=images, covis_edges=ce, covis_inliers=ci, covis_weight=cw, conn_edges=ne, conn_metres=nm,
        grid=grid, extractor=str(man.get("extractor", "")), vpr_model=str(man.get("vpr_model", "")),
        meta={str(k): str(v) for k, v in meta.items()} if isinstance(meta, dict) else {},
    )


def storage_summary(folder: str | Path) -> dict[str, int]:
    """Bytes per part of a saved map (from its manifest), like the paper's storage tables."""
    man = read_manifest(Path(folder))
    out = {"graph_bytes": 0, "descriptor_bytes": 0, "feature_bytes": 0, "image_bytes": 0, "other_bytes": 0}
    for rel, entry in man["files"].items():
        size = int(entry.get("bytes", 0))
        if rel.startswith(("graph/", "nodes/", "grid/")):
            out["graph_bytes"] += size
        elif rel.startswith("vpr/"):
            out["descriptor_bytes"] += size
        elif rel.startswith("features/"):
            out["feature_bytes"] += size
        elif rel.startswith("images/"):
            out["image_bytes"] += size
        else:
            out["other_bytes"] += size
    out["manifest_bytes"] = (Path(folder) / MANIFEST).stat().st_size
    return out
