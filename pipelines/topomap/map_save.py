"""Writing a map folder in the current format (`io.py` describes the format and loads it).

`save_map` writes atomically; `map_arrays` gives every array as stored (descriptors encoded
as `MappingParams.descriptor_bytes` says), so a benchmark can size a map without writing it.
"""

from __future__ import annotations

import io
import json
import shutil
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from litevloc.base.params.mapping import MappingParams
from litevloc.pipelines.topomap.descriptor_codec import check_layout, encode, train, training_rows
from litevloc.pipelines.topomap.io import FORMAT, MANIFEST, VERSION, MapFormatError, sha256_hex
from litevloc.pipelines.topomap.types import FeatureStore, TopoMap, keypoints_to_fixed

DEFAULT_DESCRIPTOR_BYTES = MappingParams.descriptor_bytes  # the one default: MappingParams


def _npy_bytes(a: NDArray[Any]) -> bytes:
    buf = io.BytesIO()
    np.save(buf, np.ascontiguousarray(a), allow_pickle=False)
    return buf.getvalue()


def quantise(v: NDArray[np.floating]) -> tuple[NDArray[np.int8], NDArray[np.float32]]:
    """Rows -> int8 codes and per-row scales, v ~= codes * scale."""
    a = np.asarray(v, dtype=np.float32)
    scale = np.maximum(np.abs(a).max(axis=1), 1e-12) / np.float32(127.0)
    codes = np.clip(np.round(a / scale[:, None]), -127, 127).astype(np.int8)
    return codes, scale.astype(np.float32)


NodeDescriptors = Callable[[int], NDArray[np.float32]]  # node id -> (n_i, D) float32 descriptors


def _int8_codes(descriptor_bytes: int, dim: int) -> bool:
    """Float descriptors stored as int8 codes + row scales: asked for (0), or no fewer bytes
    than dimensions (a quantiser could not be smaller)."""
    return descriptor_bytes == 0 or descriptor_bytes >= dim


def _encode_float(rows: NodeDescriptors, counts: Sequence[int], dim: int,
                  descriptor_bytes: int) -> dict[str, NDArray[Any]]:
    """Float descriptors, node by node (memory holds the codes, not a float copy of all), as
    int8 codes + row scales (`descriptor_bytes` 0, or no fewer than the dimensions) or
    product-quantiser codes + codebook."""
    n = len(counts)
    if _int8_codes(descriptor_bytes, dim):
        parts = [quantise(rows(i).reshape(-1, dim)) for i in range(n)]
        return {"features/descriptors.npy": np.concatenate([c for c, _ in parts]).reshape(-1, dim),
                "features/descriptor_scale.npy": np.concatenate([sc for _, sc in parts]).astype(np.float32)}
    try:
        check_layout(dim, descriptor_bytes)
    except ValueError as exc:
        raise MapFormatError(f"mapping.descriptor_bytes: {exc}") from exc
    offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    pick = training_rows(counts)
    owner = np.searchsorted(offsets, pick, side="right") - 1
    sample = [rows(int(i))[pick[owner == i] - offsets[i]] for i in np.unique(owner)]
    book = train(np.concatenate(sample) if sample else np.zeros((0, dim), np.float32), descriptor_bytes)
    codes = [encode(rows(i).reshape(-1, dim), book) for i in range(n)]
    return {"features/descriptors.npy": np.concatenate(codes).reshape(-1, descriptor_bytes) if codes
            else np.zeros((0, descriptor_bytes), np.uint8),
            "features/descriptor_codebook.npy": book}


def map_arrays(m: TopoMap, descriptor_bytes: int = DEFAULT_DESCRIPTOR_BYTES) -> dict[str, NDArray[Any]]:
    """The map's arrays keyed by their relative file path; float local descriptors encoded
    as `descriptor_bytes` says (`MappingParams.descriptor_bytes`: 0 = int8 codes + row
    scales, else that many product-quantiser bytes). A loaded map already in that encoding
    keeps its codes as they are (re-saving is lossless); any other is decoded and re-encoded."""
    depth: NDArray[np.float16] | None = None
    enc: dict[str, NDArray[Any]]
    if isinstance(m.features, FeatureStore):  # a loaded map: its arrays as they are where possible
        fs = m.features
        offsets, kps, scores = fs.offsets, fs.keypoints, fs.scores
        depth = None if fs.depth is None else _depth16(np.asarray(fs.depth))
        counts = np.diff(np.asarray(offsets)).tolist()
        if fs.codebook is not None and descriptor_bytes == fs.codebook.shape[0]:
            enc = {"features/descriptors.npy": fs.descriptors, "features/descriptor_codebook.npy": fs.codebook}
        elif fs.descriptor_scale is not None and _int8_codes(descriptor_bytes, fs.descriptors.shape[1]):
            enc = {"features/descriptors.npy": fs.descriptors, "features/descriptor_scale.npy": fs.descriptor_scale}
        elif fs.codebook is not None or np.dtype(fs.descriptors.dtype).kind in "fi":
            dim = fs.codebook.shape[0] * fs.codebook.shape[2] if fs.codebook is not None else fs.descriptors.shape[1]
            enc = _encode_float(lambda i: np.asarray(fs.node_descriptors(i), np.float32), counts, dim,
                                descriptor_bytes)
        else:  # binary descriptors: stored as they are
            enc = {"features/descriptors.npy": fs.descriptors}
    else:
        feats = list(m.features)
        counts = [len(f.keypoints) for f in feats]
        offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        desc_dim = feats[0].descriptors.shape[1] if feats and feats[0].descriptors.ndim == 2 else 0
        desc_dtype = feats[0].descriptors.dtype if feats else np.float32
        kps = np.concatenate([f.keypoints for f in feats]).astype(np.float32).reshape(-1, 2)
        scores = np.concatenate([f.scores for f in feats]).astype(np.float32)
        node_depth = [getattr(f, "depth", None) for f in feats]  # only NodeFeatures carry it
        if any(d is not None for d in node_depth):  # nodes without it: 0 (none)
            depth = _depth16(np.concatenate([np.zeros(len(f.keypoints), np.float32) if d is None
                                             else np.asarray(d, np.float32).reshape(-1)
                                             for f, d in zip(feats, node_depth, strict=True)]))
        if np.dtype(desc_dtype).kind == "f":
            enc = _encode_float(lambda i: np.asarray(feats[i].descriptors, np.float32), counts, desc_dim,
                                descriptor_bytes)
        else:
            enc = {"features/descriptors.npy": np.concatenate([f.descriptors for f in feats], dtype=desc_dtype,
                                                              casting="same_kind").reshape(-1, desc_dim)}
    g = m.grid
    vpr_codes, vpr_scale = quantise(m.vpr)
    out: dict[str, NDArray[Any]] = {
        "nodes/T_map_camera.npy": m.T_map_camera.astype(np.float64),
        "nodes/K.npy": m.K.astype(np.float64),
        "nodes/image_size.npy": m.image_size.astype(np.int32),
        "nodes/t_ns.npy": m.t_ns.astype(np.int64),
        "nodes/frame_index.npy": m.frame_index.astype(np.int64),
        "vpr/descriptors.npy": vpr_codes,
        "vpr/scale.npy": vpr_scale,
        "features/offsets.npy": np.asarray(offsets, np.int64),
        "features/keypoints.npy": stored_keypoints(kps),
        "features/scores.npy": _scores16(scores),
        "graph/covisibility_edges.npy": m.covis_edges.astype(np.int64).reshape(-1, 2),
        "graph/covisibility_inliers.npy": m.covis_inliers.astype(np.int32),
        "graph/covisibility_weight.npy": m.covis_weight.astype(np.float32),
        "graph/connectivity_edges.npy": m.conn_edges.astype(np.int64).reshape(-1, 2),
        "graph/connectivity_metres.npy": m.conn_metres.astype(np.float32),
        "grid/cells.npy": g.cells.astype(np.uint8),
        "grid/frame.npy": np.concatenate([g.origin, [g.resolution], g.up, g.plane_axes.reshape(6)]).astype(np.float64),
    }
    out.update((rel, np.asarray(a)) for rel, a in enc.items())
    if depth is not None:
        out["features/depth.npy"] = depth
    return out


def stored_keypoints(kps: NDArray[Any]) -> NDArray[Any]:
    """Keypoints as stored: uint16 steps of 1/8 px (format 3; kept as they are when already
    so), or float32 where a coordinate lies beyond the fixed-point range (images > 8191 px)."""
    if np.dtype(kps.dtype) == np.uint16:
        return np.asarray(kps)
    k = np.asarray(kps, np.float32).reshape(-1, 2)
    try:
        return keypoints_to_fixed(k)
    except ValueError:  # beyond the fixed-point range
        return k


def _scores16(scores: NDArray[Any]) -> NDArray[np.float16]:
    """Keypoint scores as stored (format 3): float16, clipped to its range (scores only rank
    a node's keypoints, which are stored strongest first)."""
    s = np.asarray(scores)
    if s.dtype == np.float16:
        return s
    f16 = float(np.finfo(np.float16).max)
    return np.clip(np.asarray(s, np.float32), -f16, f16).astype(np.float16)


def _depth16(z: NDArray[np.floating]) -> NDArray[np.float16]:
    """Keypoint depths (metres, NaN/<= 0 = none) as stored: float16, 0 = none (float16 keeps
    3 significant digits: 4 mm at 5 m)."""
    z = np.asarray(z, np.float32)
    return np.where(np.isfinite(z) & (z > 0) & (z < 65000), z, 0).astype(np.float16)


def save_map(m: TopoMap, folder: str | Path, overwrite: bool = False,
             descriptor_bytes: int = DEFAULT_DESCRIPTOR_BYTES) -> Path:
    """Write the map atomically (a temporary sibling folder renamed into place); float local
    descriptors encoded as `descriptor_bytes` says (see `map_arrays`)."""
    dst = Path(folder)
    if dst.exists() and not overwrite:
        raise MapFormatError(f"{dst} already exists (pass overwrite=True / --force to replace it)")
    tmp = dst.with_name(dst.name + ".partial")
    if tmp.exists():
        shutil.rmtree(tmp)
    entries: dict[str, dict[str, Any]] = {}

    def put(rel: str, data: bytes) -> None:  # one file at a time: memory holds one file's bytes
        p = tmp / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_bytes(data)
        entries[rel] = {"sha256": sha256_hex(data), "bytes": len(data)}

    arrays = map_arrays(m, descriptor_bytes)
    codec = ("pq" if "features/descriptor_codebook.npy" in arrays else
             "int8" if "features/descriptor_scale.npy" in arrays else "binary")
    for rel in list(arrays):
        put(rel, _npy_bytes(arrays.pop(rel)))
    for i, jpg in enumerate(m.images_jpeg):
        put(f"images/{i:06d}.jpg", jpg)
    manifest = {
        "format": FORMAT,
        "version": VERSION,
        "nodes": m.n_nodes,
        "covisibility_edges": len(m.covis_edges),
        "connectivity_edges": len(m.conn_edges),
        "extractor": m.extractor,
        "vpr_model": m.vpr_model,
        "vpr_dim": int(m.vpr.shape[1]),
        "descriptor_codec": codec,
        "meta": dict(sorted(m.meta.items())),
        "files": dict(sorted(entries.items())),
    }
    (tmp / MANIFEST).write_text(json.dumps(manifest, indent=1, sort_keys=True) + "\n")
    if dst.exists():
        shutil.rmtree(dst)
    tmp.rename(dst)
    return dst
