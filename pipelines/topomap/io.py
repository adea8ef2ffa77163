"""On-disk map format (version 1) and its validating loader.

A map is a folder:

```
manifest.json                 format, version, counts, model names, sha256 + size per file
nodes/T_map_camera.npy        (N,4,4) float64     nodes/K.npy            (N,3,3) float64
nodes/image_size.npy          (N,2) int32 (w,h)   nodes/t_ns.npy         (N,) int64
nodes/frame_index.npy         (N,) int64          vpr/descriptors.npy    (N,D) int8, vpr/scale.npy (N,) float32
features/offsets.npy          (N+1,) int64: node i owns rows offsets[i]:offsets[i+1]
features/keypoints.npy        (M,2) float32       features/scores.npy    (M,) float32
features/descriptors.npy      (M,Df) float16 (or uint8 for binary descriptors)
graph/covisibility_edges.npy  (E,2) int64 i<j     graph/covisibility_inliers.npy (E,) int32
graph/covisibility_weight.npy (E,) float32 (0,1]  graph/connectivity_edges.npy   (F,2) int64 i<j
graph/connectivity_metres.npy (F,) float32 >= 0
grid/cells.npy                (H,W) uint8 {0 unknown, 1 free, 2 occupied}
grid/frame.npy                (12,) float64: origin(2), resolution, up(3), plane axes(6)
images/NNNNNN.jpg             keyframe images (JPEG), one per node
```

Local float descriptors are stored as float16 (half the bytes). Place descriptors are
stored as int8 with one float32 scale per node (symmetric quantisation, a quarter of the
bytes: 1280-d EfficientNet-GeM costs 1.3 KB per node); cosine similarities change by
< 2e-3, far below the margins that rank places. The loader returns float32 unit vectors.
Plain `.npy` files (never pickle; loaded with `allow_pickle=False`) so building twice
gives byte-identical files. `load_map` checks everything and raises `MapFormatError`
naming the file and the problem: missing, unlisted, truncated (size), checksum, wrong
dtype/shape, non-finite values, non-rigid poses, out-of-range edges, wrong version.
"""

from __future__ import annotations

import hashlib
import io
import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from litevloc.base.errors import LiteVLocError
from litevloc.pipelines.geometry import is_rigid
from litevloc.pipelines.topomap.types import NodeFeatures, OccupancyGrid, TopoMap

FORMAT = "litevloc-map"
VERSION = 1
MANIFEST = "manifest.json"


class MapFormatError(LiteVLocError, ValueError):
    """A map folder is missing, corrupt or inconsistent; the message names the file."""


def _sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _npy_bytes(a: NDArray[Any]) -> bytes:
    buf = io.BytesIO()
    np.save(buf, np.ascontiguousarray(a), allow_pickle=False)
    return buf.getvalue()


def _quantise(v: NDArray[np.floating]) -> tuple[NDArray[np.int8], NDArray[np.float32]]:
    """Rows -> int8 codes and per-row scales, v ~= codes * scale."""
    a = np.asarray(v, dtype=np.float32)
    scale = np.maximum(np.abs(a).max(axis=1), 1e-12) / np.float32(127.0)
    codes = np.clip(np.round(a / scale[:, None]), -127, 127).astype(np.int8)
    return codes, scale.astype(np.float32)


def map_arrays(m: TopoMap) -> dict[str, NDArray[Any]]:
    """The map's arrays keyed by their relative file path."""
    offsets = np.concatenate([[0], np.cumsum([len(f.keypoints) for f in m.features])]).astype(np.int64)
    desc_dim = m.features[0].descriptors.shape[1] if m.features and m.features[0].descriptors.ndim == 2 else 0
    desc_dtype = m.features[0].descriptors.dtype if m.features else np.float32
    if np.dtype(desc_dtype).kind == "f":
        desc_dtype = np.float16
    g = m.grid
    vpr_codes, vpr_scale = _quantise(m.vpr)
    return {
        "nodes/T_map_camera.npy": m.T_map_camera.astype(np.float64),
        "nodes/K.npy": m.K.astype(np.float64),
        "nodes/image_size.npy": m.image_size.astype(np.int32),
        "nodes/t_ns.npy": m.t_ns.astype(np.int64),
        "nodes/frame_index.npy": m.frame_index.astype(np.int64),
        "vpr/descriptors.npy": vpr_codes,
        "vpr/scale.npy": vpr_scale,
        "features/offsets.npy": offsets,
        "features/keypoints.npy": np.concatenate([f.keypoints for f in m.features]).astype(np.float32).reshape(-1, 2),
        "features/scores.npy": np.concatenate([f.scores for f in m.features]).astype(np.float32),
        "features/descriptors.npy": np.concatenate([f.descriptors for f in m.features]).astype(desc_dtype)
        .reshape(-1, desc_dim),
        "graph/covisibility_edges.npy": m.covis_edges.astype(np.int64).reshape(-1, 2),
        "graph/covisibility_inliers.npy": m.covis_inliers.astype(np.int32),
        "graph/covisibility_weight.npy": m.covis_weight.astype(np.float32),
        "graph/connectivity_edges.npy": m.conn_edges.astype(np.int64).reshape(-1, 2),
        "graph/connectivity_metres.npy": m.conn_metres.astype(np.float32),
        "grid/cells.npy": g.cells.astype(np.uint8),
        "grid/frame.npy": np.concatenate([g.origin, [g.resolution], g.up, g.plane_axes.reshape(6)]).astype(np.float64),
    }


def save_map(m: TopoMap, folder: str | Path, overwrite: bool = False) -> Path:
    """Write the map atomically (a temporary sibling folder renamed into place)."""
    dst = Path(folder)
    if dst.exists() and not overwrite:
        raise MapFormatError(f"{dst} already exists (pass overwrite=True / --force to replace it)")
    tmp = dst.with_name(dst.name + ".partial")
    if tmp.exists():
        shutil.rmtree(tmp)
    files: dict[str, bytes] = {k: _npy_bytes(v) for k, v in map_arrays(m).items()}
    for i, jpg in enumerate(m.images_jpeg):
        files[f"images/{i:06d}.jpg"] = jpg
    for rel, data in files.items():
        p = tmp / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_bytes(data)
    manifest = {
        "format": FORMAT,
        "version": VERSION,
        "nodes": m.n_nodes,
        "covisibility_edges": len(m.covis_edges),
        "connectivity_edges": len(m.conn_edges),
        "extractor": m.extractor,
        "vpr_model": m.vpr_model,
        "vpr_dim": int(m.vpr.shape[1]),
        "meta": dict(sorted(m.meta.items())),
        "files": {rel: {"sha256": _sha256(data), "bytes": len(data)} for rel, data in sorted(files.items())},
    }
    (tmp / MANIFEST).write_text(json.dumps(manifest, indent=1, sort_keys=True) + "\n")
    if dst.exists():
        shutil.rmtree(dst)
    tmp.rename(dst)
    return dst


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
    if man.get("version") != VERSION:
        raise _fail(folder, MANIFEST, f"unsupported map version {man.get('version')!r} (this build reads {VERSION})")
    files = man.get("files")
    if not isinstance(files, dict):
        raise _fail(folder, MANIFEST, "'files' must be a mapping of path -> {sha256, bytes}")
    n = man.get("nodes")
    if not isinstance(n, int) or n < 1:
        raise _fail(folder, MANIFEST, f"'nodes' must be a positive integer, got {n!r}")
    return man


def _read_verified(folder: Path, rel: str, entry: Any) -> bytes:
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
    data = p.read_bytes()
    if len(data) != entry["bytes"]:
        raise _fail(folder, rel, f"truncated or extended: {len(data)} bytes, manifest says {entry['bytes']}")
    if _sha256(data) != entry["sha256"]:
        raise _fail(folder, rel, "checksum mismatch (file modified or corrupt)")
    return data


def _array(folder: Path, rel: str, data: bytes, dtype: Any, shape: tuple[int | None, ...]) -> NDArray[Any]:
    try:
        a = np.load(io.BytesIO(data), allow_pickle=False)
    except (ValueError, OSError, EOFError) as exc:
        raise _fail(folder, rel, f"not a readable .npy array ({exc})") from exc
    dtypes = dtype if isinstance(dtype, tuple) else (dtype,)
    if a.dtype not in [np.dtype(d) for d in dtypes]:
        raise _fail(folder, rel, f"dtype {a.dtype}, expected {' or '.join(str(np.dtype(d)) for d in dtypes)}")
    if a.ndim != len(shape) or any(s is not None and s != d for s, d in zip(shape, a.shape, strict=True)):
        want = "x".join("*" if s is None else str(s) for s in shape)
        raise _fail(folder, rel, f"shape {a.shape}, expected {want}")
    if a.dtype.kind == "f" and not np.all(np.isfinite(a)):
        raise _fail(folder, rel, "contains NaN or infinity")
    return a


def load_map(folder: str | Path) -> TopoMap:
    """Load and validate a map folder (see module docstring); MapFormatError on any problem."""
    root = Path(folder)
    man = read_manifest(root)
    files: dict[str, Any] = man["files"]
    N = int(man["nodes"])
    required = [
        "nodes/T_map_camera.npy", "nodes/K.npy", "nodes/image_size.npy", "nodes/t_ns.npy", "nodes/frame_index.npy",
        "vpr/descriptors.npy", "vpr/scale.npy", "features/offsets.npy", "features/keypoints.npy", "features/scores.npy",
        "features/descriptors.npy", "graph/covisibility_edges.npy", "graph/covisibility_inliers.npy",
        "graph/covisibility_weight.npy", "graph/connectivity_edges.npy", "graph/connectivity_metres.npy",
        "grid/cells.npy", "grid/frame.npy",
    ] + [f"images/{i:06d}.jpg" for i in range(N)]
    for rel in required:
        if rel not in files:
            raise _fail(root, rel, "not listed in manifest.json")
    raw = {rel: _read_verified(root, rel, files[rel]) for rel in required}

    def arr(rel: str, dtype: Any, shape: tuple[int | None, ...]) -> NDArray[Any]:
        return _array(root, rel, raw[rel], dtype, shape)

    T = arr("nodes/T_map_camera.npy", np.float64, (N, 4, 4))
    for i in range(N):
        if not is_rigid(T[i], atol=1e-5):
            raise _fail(root, "nodes/T_map_camera.npy", f"pose of node {i} is not a rigid transform")
    K = arr("nodes/K.npy", np.float64, (N, 3, 3))
    if np.any(K[:, 0, 0] <= 0) or np.any(K[:, 1, 1] <= 0):
        raise _fail(root, "nodes/K.npy", "focal lengths must be positive")
    size = arr("nodes/image_size.npy", np.int32, (N, 2))
    if np.any(size <= 0):
        raise _fail(root, "nodes/image_size.npy", "image sizes must be positive")
    t_ns = arr("nodes/t_ns.npy", np.int64, (N,))
    frame_index = arr("nodes/frame_index.npy", np.int64, (N,))
    codes = arr("vpr/descriptors.npy", np.int8, (N, None))
    vpr_scale = arr("vpr/scale.npy", np.float32, (N,))
    vpr = codes.astype(np.float32) * vpr_scale[:, None]
    norms = np.linalg.norm(vpr, axis=1, keepdims=True)
    if np.any(norms < 1e-6):
        raise _fail(root, "vpr/descriptors.npy", "a descriptor is zero")
    vpr = (vpr / norms).astype(np.float32)
    if vpr.shape[1] != man.get("vpr_dim"):
        raise _fail(root, "vpr/descriptors.npy", f"dimension {vpr.shape[1]} != manifest vpr_dim {man.get('vpr_dim')}")
    off = arr("features/offsets.npy", np.int64, (N + 1,))
    kps = arr("features/keypoints.npy", np.float32, (None, 2))
    M = len(kps)
    if off[0] != 0 or off[-1] != M or np.any(np.diff(off) < 0):
        raise _fail(root, "features/offsets.npy", f"must rise from 0 to {M} (keypoint count)")
    scores = arr("features/scores.npy", np.float32, (M,))
    desc = arr("features/descriptors.npy", (np.float16, np.uint8), (M, None))
    if desc.dtype == np.float16:
        desc = desc.astype(np.float32)
    feats = []
    for i in range(N):
        a, b = int(off[i]), int(off[i + 1])
        w, h = int(size[i, 0]), int(size[i, 1])
        k = kps[a:b]
        if len(k) and (k.min() < -0.5 or np.any(k[:, 0] > w - 0.5) or np.any(k[:, 1] > h - 0.5)):
            raise _fail(root, "features/keypoints.npy", f"keypoints of node {i} fall outside its {w}x{h} image")
        feats.append(NodeFeatures(k, desc[a:b], scores[a:b], (w, h)))
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
    cells = arr("grid/cells.npy", np.uint8, (None, None))
    if cells.size and cells.max() > 2:
        raise _fail(root, "grid/cells.npy", "cell values must be 0, 1 or 2")
    gf = arr("grid/frame.npy", np.float64, (12,))
    if gf[2] <= 0:
        raise _fail(root, "grid/frame.npy", "resolution must be positive")
    images = []
    for i in range(N):
        rel = f"images/{i:06d}.jpg"
        data = raw[rel]
        if data[:2] != b"\xff\xd8" or b"\xff\xd9" not in data[-16:]:
            raise _fail(root, rel, "not a complete JPEG")
        images.append(data)
    meta = man.get("meta", {})
    return TopoMap(
        T_map_camera=T, K=K, image_size=size, t_ns=t_ns, frame_index=frame_index, vpr=vpr, features=feats,
        images_jpeg=images, covis_edges=ce, covis_inliers=ci, covis_weight=cw, conn_edges=ne, conn_metres=nm,
        grid=OccupancyGrid(cells, gf[0:2].copy(), float(gf[2]), gf[3:6].copy(), gf[6:12].reshape(2, 3).copy()),
        extractor=str(man.get("extractor", "")), vpr_model=str(man.get("vpr_model", "")),
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
