"""In-memory map-lite topo-metric map.

A `TopoMap` holds N keyframe nodes and two graphs over them:

* covisibility graph (CvG, for localization): undirected edges between keyframes whose
  local features verify geometrically; weight in (0, 1] from the inlier count;
* connectivity graph (CnG, for planning): undirected edges between mutually reachable
  keyframes, weighted in metres.

Frames: node poses are `T_map_camera` (camera optical frame in the map frame). The
ground plane for the occupancy grid is orthogonal to `up` (unit 3-vector in the map
frame); grid cell (row, col) covers plane coordinates `origin + (col, row) * resolution`
along the two in-plane axes `plane_axes` (2x3).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any, Protocol, overload

import numpy as np
from numpy.typing import NDArray

from litevloc.pipelines.topomap.descriptor_codec import decode
from litevloc.pipelines.topomap.node_index import NodeIndex, connectivity_matrix, neighbour_lists


class FeatureSet(Protocol):
    """Local features of one image (structurally matches `litevloc.models.types.Features`)."""

    @property
    def keypoints(self) -> NDArray[np.float32]: ...  # (N, 2) pixels (u, v)

    @property
    def descriptors(self) -> NDArray[Any]: ...  # (N, D)

    @property
    def scores(self) -> NDArray[np.float32]: ...  # (N,)


@dataclass(frozen=True, eq=False)
class NodeFeatures:
    """Cached local features of a keyframe (keypoints in the stored keyframe image's pixels).

    `depth` (N,) float32: the mapping frame's depth at each keypoint along the camera's z
    axis (metres; NaN where there was none), or None for maps made without it."""

    keypoints: NDArray[np.float32]
    descriptors: NDArray[Any]
    scores: NDArray[np.float32]
    image_size: tuple[int, int]  # (width, height)
    depth: NDArray[np.float32] | None = None


KEYPOINT_SUBPIXELS = 8  # fixed-point keypoints (map format 3): uint16 steps of 1/8 pixel from -0.5 px
KEYPOINT_FIXED_MAX = (65535 / KEYPOINT_SUBPIXELS) - 0.5  # largest storable coordinate, pixels


def keypoints_to_fixed(kp: NDArray[np.floating]) -> NDArray[np.uint16]:
    """(M, 2) pixel coordinates in [-0.5, KEYPOINT_FIXED_MAX] -> uint16 steps of 1/8 px
    (rounding moves a keypoint by <= 1/16 px); ValueError outside that range."""
    k = np.asarray(kp, np.float32)
    if k.size and not (k.min() >= -0.5 and k.max() <= KEYPOINT_FIXED_MAX):
        raise ValueError(f"keypoints must lie in [-0.5, {KEYPOINT_FIXED_MAX}] px for fixed-point storage")
    return np.round((k + np.float32(0.5)) * np.float32(KEYPOINT_SUBPIXELS)).astype(np.uint16)


def keypoints_from_fixed(q: NDArray[Any]) -> NDArray[np.float32]:
    """uint16 steps of 1/8 px -> float32 pixels (the inverse of `keypoints_to_fixed`)."""
    return (np.asarray(q, np.float32) * np.float32(1 / KEYPOINT_SUBPIXELS) - np.float32(0.5)).astype(np.float32)


class FeatureStore(Sequence[Any]):
    """The cached local features of all N nodes in concatenated arrays; item i is node i's
    `NodeFeatures`, made on access (no per-node objects or copies at load time).

    offsets: (N+1,) int64, node i owns rows offsets[i]:offsets[i+1] of
    keypoints (M, 2) float32 pixels or uint16 fixed point (`keypoints_to_fixed`, map format
    3), descriptors (M, D) and scores (M,) float32 or float16 (each may be a read-only
    memory map); keypoints and scores come out as float32 per node. Float descriptors are
    float16, int8 codes with one float32 scale per row in `descriptor_scale` (M,) (map
    format 2), or product-quantiser codes (M, S) uint8 with their `codebook` (S, K, D/S)
    float32 (map format 3, `descriptor_codec`); each comes out as float32 (M_node, D) per
    node. Binary (uint8) descriptors without a codebook are returned as they are. `depth` (M,) (optional):
    keypoint depth in metres, 0 = none; returned per node as float32 with NaN for none;
    image_size: (N, 2) int (width, height). `convert` (optional) is applied to each
    node's NodeFeatures on access (e.g. to the model layer's feature type)."""

    def __init__(self, offsets: NDArray[np.int64], keypoints: NDArray[Any], descriptors: NDArray[Any],
                 scores: NDArray[Any], image_size: NDArray[np.integer],
                 convert: Callable[[NodeFeatures], Any] | None = None,
                 descriptor_scale: NDArray[np.float32] | None = None,
                 depth: NDArray[np.floating] | None = None, codebook: NDArray[np.float32] | None = None) -> None:
        if (descriptors.dtype == np.int8) != (descriptor_scale is not None):
            raise ValueError("int8 descriptors need descriptor_scale (one float32 per row), and only they")
        if codebook is not None and (descriptors.dtype != np.uint8 or codebook.ndim != 3
                                     or descriptors.shape[1:] != codebook.shape[:1]):
            raise ValueError(f"product-quantiser codes must be (M, S) uint8 for an (S, K, d) codebook, got "
                             f"{descriptors.dtype} {descriptors.shape} for {codebook.shape}")
        self.codebook = codebook
        self.offsets, self.keypoints, self.descriptors, self.scores = offsets, keypoints, descriptors, scores
        self.descriptor_scale = descriptor_scale
        self.depth = depth  # (M,) metres, 0 = none (as stored), or None
        self.image_size = image_size
        self.convert = convert

    def __len__(self) -> int:
        return len(self.offsets) - 1

    def _node(self, i: int) -> Any:
        n = len(self)
        if i < 0:
            i += n
        if not 0 <= i < n:
            raise IndexError(f"node {i} not in 0..{n - 1}")
        a, b = int(self.offsets[i]), int(self.offsets[i + 1])
        d = self.node_descriptors(i)
        z = None
        if self.depth is not None:
            z = np.asarray(self.depth[a:b], np.float32)
            z = np.where(z > 0, z, np.float32(np.nan))
        kp = self.keypoints[a:b]
        kp = keypoints_from_fixed(kp) if kp.dtype == np.uint16 else np.asarray(kp)
        f = NodeFeatures(kp, d, np.asarray(self.scores[a:b], np.float32),
                         (int(self.image_size[i, 0]), int(self.image_size[i, 1])), z)
        return f if self.convert is None else self.convert(f)

    def node_descriptors(self, i: int) -> NDArray[Any]:
        """Node i's descriptors decoded from what the store holds: float32 (M_node, D) for float
        descriptors (product-quantiser codes, int8 codes + scales, float16), binary as they are
        (no `convert`)."""
        a, b = int(self.offsets[i]), int(self.offsets[i + 1])
        d = self.descriptors[a:b]
        if self.codebook is not None:
            return decode(d, self.codebook)
        if self.descriptor_scale is not None:
            return np.asarray(d.astype(np.float32) * self.descriptor_scale[a:b, None], np.float32)
        return d.astype(np.float32) if d.dtype == np.float16 else np.asarray(d)

    @overload
    def __getitem__(self, i: int) -> Any: ...

    @overload
    def __getitem__(self, i: slice) -> list[Any]: ...

    def __getitem__(self, i: int | slice) -> Any:
        if isinstance(i, slice):
            return [self._node(k) for k in range(*i.indices(len(self)))]
        return self._node(int(i))

    def __iter__(self) -> Iterator[Any]:
        return (self._node(i) for i in range(len(self)))

    def mapped(self, convert: Callable[[NodeFeatures], Any]) -> FeatureStore:
        """The same store with `convert` applied to each node's features on access."""
        return FeatureStore(self.offsets, self.keypoints, self.descriptors, self.scores, self.image_size, convert,
                            self.descriptor_scale, self.depth, self.codebook)


@dataclass(frozen=True, eq=False)
class OccupancyGrid:
    """2D grid on the ground plane. cells: 0 unknown, 1 free (observed floor level), 2 occupied."""

    cells: NDArray[np.uint8]  # (H, W)
    origin: NDArray[np.float64]  # (2,) plane coordinates (metres) of cell (0, 0)'s corner
    resolution: float  # metres per cell
    up: NDArray[np.float64]  # (3,) unit, map frame
    plane_axes: NDArray[np.float64]  # (2, 3) orthonormal in-plane axes, map frame

    UNKNOWN = 0
    FREE = 1
    OCCUPIED = 2

    def to_plane(self, points_map: NDArray[np.floating]) -> NDArray[np.float64]:
        """(N, 3) map points -> (N, 2) plane coordinates in metres."""
        return np.asarray(points_map, dtype=np.float64) @ self.plane_axes.T

    def cell_of(self, xy: NDArray[np.floating]) -> NDArray[np.intp]:
        """(N, 2) plane coordinates -> (N, 2) integer (row, col); may be out of range."""
        ij = np.floor((np.asarray(xy, dtype=np.float64) - self.origin) / self.resolution).astype(np.intp)
        return ij[:, ::-1]


@dataclass(frozen=True, eq=False)
class TopoMap:
    """The map. Arrays are indexed by node id 0..N-1."""

    T_map_camera: NDArray[np.float64]  # (N, 4, 4)
    K: NDArray[np.float64]  # (N, 3, 3) intrinsics of the stored keyframe images
    image_size: NDArray[np.int32]  # (N, 2) (width, height)
    t_ns: NDArray[np.int64]  # (N,) capture times
    frame_index: NDArray[np.int64]  # (N,) index of the frame in the source stream
    vpr: NDArray[np.float32]  # (N, D) L2-normalised place descriptors
    features: Sequence[FeatureSet]  # NodeFeatures (or the model layer's Features) list, or a FeatureStore
    images_jpeg: Sequence[bytes]  # list, or a lazy verified reader (loaded maps)
    covis_edges: NDArray[np.int64]  # (E, 2), i < j
    covis_inliers: NDArray[np.int32]  # (E,)
    covis_weight: NDArray[np.float32]  # (E,)
    conn_edges: NDArray[np.int64]  # (F, 2), i < j
    conn_metres: NDArray[np.float32]  # (F,)
    grid: OccupancyGrid
    extractor: str = ""
    vpr_model: str = ""
    meta: dict[str, str] = field(default_factory=dict)

    @property
    def n_nodes(self) -> int:
        return len(self.T_map_camera)

    @property
    def positions(self) -> NDArray[np.float64]:
        """(N, 3) camera centres in the map frame."""
        return self.T_map_camera[:, :3, 3]

    @cached_property
    def node_index(self) -> NodeIndex:
        """KD-tree over the node positions (built on first use, once per map)."""
        return NodeIndex(self.positions)

    @cached_property
    def covisibility_lists(self) -> list[list[int]]:
        """Covisible neighbours of each node, strongest edge first (ties by id); built once."""
        return neighbour_lists(self.covis_edges, self.covis_weight, self.n_nodes)

    @cached_property
    def _covis_weight_of(self) -> dict[tuple[int, int], float]:
        return {(int(i), int(j)): float(w) for (i, j), w in zip(self.covis_edges.tolist(), self.covis_weight.tolist(),
                                                                 strict=True)}

    @cached_property
    def connectivity_csr(self) -> Any:
        """Connectivity graph as a symmetric scipy.sparse CSR matrix of metres (see node_index)."""
        return connectivity_matrix(self.conn_edges, self.conn_metres, self.n_nodes)

    def keypoint_depth(self, node: int) -> NDArray[np.float32] | None:
        """(N_node,) mapping depth (metres, NaN = none) at each of the node's keypoints, or None
        when the map has none (maps before format 2, features converted in memory)."""
        f = self.features
        if isinstance(f, FeatureStore):
            if f.depth is None:
                return None
            z = np.asarray(f.depth[int(f.offsets[node]):int(f.offsets[node + 1])], np.float32)
            return np.where(z > 0, z, np.float32(np.nan))
        if not getattr(f, "has_keypoint_depth", True):  # a lazy sequence that says so: no node made to find out
            return None
        d = getattr(f[node], "depth", None)
        return None if d is None else np.asarray(d, np.float32)

    def stored_features(self, node: int) -> NodeFeatures:
        """The node's features as a map stores them, keypoint depth included, whatever view
        `features` gives (a loaded map's store converted for a matcher drops the depth): what
        maps made from this one (merge, update) must carry on."""
        f = self.features[node]
        size = getattr(f, "image_size", None)
        if size is None:
            size = (int(self.image_size[node, 0]), int(self.image_size[node, 1]))
        return NodeFeatures(np.asarray(f.keypoints, np.float32), np.asarray(f.descriptors),
                            np.asarray(f.scores, np.float32), (int(size[0]), int(size[1])), self.keypoint_depth(node))

    def covisible_neighbours(self, node: int) -> list[tuple[int, float]]:
        """(neighbour id, weight) pairs of `node` in the covisibility graph, strongest first."""
        w = self._covis_weight_of
        return [(int(n), w[(min(node, n), max(node, n))]) for n in self.covisibility_lists[node]]
