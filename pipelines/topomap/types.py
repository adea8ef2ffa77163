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

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
from numpy.typing import NDArray


class FeatureSet(Protocol):
    """Local features of one image (structurally matches `litevloc.models.types.Features`)."""

    @property
    def keypoints(self) -> NDArray[np.float32]: ...  # (N, 2) pixels (u, v)

    @property
    def descriptors(self) -> NDArray: ...  # (N, D)

    @property
    def scores(self) -> NDArray[np.float32]: ...  # (N,)


@dataclass(frozen=True, eq=False)
class NodeFeatures:
    """Cached local features of a keyframe (keypoints in the stored keyframe image's pixels)."""

    keypoints: NDArray[np.float32]
    descriptors: NDArray
    scores: NDArray[np.float32]
    image_size: tuple[int, int]  # (width, height)


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
    features: list[NodeFeatures]
    images_jpeg: list[bytes]
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

    def covisible_neighbours(self, node: int) -> list[tuple[int, float]]:
        """(neighbour id, weight) pairs of `node` in the covisibility graph."""
        out = []
        for (i, j), w in zip(self.covis_edges, self.covis_weight, strict=True):
            if i == node:
                out.append((int(j), float(w)))
            elif j == node:
                out.append((int(i), float(w)))
        return out
