"""What changed between two versions of a map (`litevloc map diff OLD NEW`).

Nodes are matched by identity, not by position: a keyframe is the same node in both maps
when its stored keyframe image is byte-identical (SHA-256 of the JPEG). Maps built, updated
or merged from the same recordings keep their keyframe images as they are, so a node keeps
its identity across versions even when its pose was re-expressed or re-optimised. Then:

* retired: in OLD, not in NEW;  added: in NEW, not in OLD;
* moved: in both, with the camera centre moved by more than `moved_m` or the orientation by
  more than `moved_deg` (both maps' `T_map_camera` are compared in their own map frames,
  so a diff across a change of map frame shows every node as moved — that is the truth);
* coverage: the ground-plane area observed by each map's occupancy grid (cells that are
  free or occupied), and how much of it the other map also observes, on a common grid;
  plus the share of each map's keyframe places (position within `place_radius_m`, viewing
  direction within `place_angle_deg`) that the other map still has a keyframe for.

Pure: arrays in, a `MapDiff` out. Plotting and file I/O live in the CLI.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from litevloc.base.errors import LiteVLocError
from litevloc.base.geometry import relative_pose_error
from litevloc.base.params.map_maintenance import DiffParams
from litevloc.pipelines.topomap.types import OccupancyGrid, TopoMap


class MapDiffError(LiteVLocError, ValueError):
    """Two maps cannot be compared (e.g. different ground planes)."""


@dataclass(frozen=True)
class CoverageDiff:
    """Observed ground-plane area (m^2) of each map's occupancy grid, on a common grid."""

    old_m2: float
    new_m2: float
    both_m2: float
    only_old_m2: float
    only_new_m2: float
    resolution_m: float


@dataclass(frozen=True, eq=False)
class MapDiff:
    """Node-level and coverage changes from OLD to NEW. Node ids are each map's own indices."""

    kept: NDArray[np.int64]  # (K, 2) (old id, new id) of nodes in both maps
    moved: NDArray[np.int64]  # (M,) indices into `kept` of the nodes that moved
    moved_m: NDArray[np.float64]  # (M,) translation of each moved node, metres
    moved_deg: NDArray[np.float64]  # (M,) rotation of each moved node, degrees
    retired: NDArray[np.int64]  # old ids
    added: NDArray[np.int64]  # new ids
    coverage: CoverageDiff
    old_places_kept: float  # share of OLD keyframe places that NEW still has a keyframe for
    new_places_in_old: float  # share of NEW keyframe places that OLD already had
    n_old: int = 0
    n_new: int = 0
    notes: tuple[str, ...] = field(default=())

    def summary(self) -> dict[str, float | int]:
        """Plain numbers for JSON and tables."""
        c = self.coverage
        return {
            "old_nodes": self.n_old, "new_nodes": self.n_new, "kept": len(self.kept), "moved": len(self.moved),
            "retired": len(self.retired), "added": len(self.added),
            "moved_max_m": float(self.moved_m.max()) if len(self.moved_m) else 0.0,
            "coverage_old_m2": c.old_m2, "coverage_new_m2": c.new_m2, "coverage_both_m2": c.both_m2,
            "coverage_only_old_m2": c.only_old_m2, "coverage_only_new_m2": c.only_new_m2,
            "old_places_kept": self.old_places_kept, "new_places_in_old": self.new_places_in_old,
        }


def node_identities(m: TopoMap) -> list[str]:
    """SHA-256 (hex) of each node's stored keyframe JPEG: the node's identity across versions."""
    return [hashlib.sha256(b).hexdigest() for b in m.images_jpeg]


def _observed_plane_points(g: OccupancyGrid) -> NDArray[np.float64]:
    """(N, 2) plane coordinates of the centres of the grid's observed cells (free or occupied)."""
    rows, cols = np.nonzero(g.cells != OccupancyGrid.UNKNOWN)
    return g.origin + (np.stack([cols, rows], axis=1).astype(np.float64) + 0.5) * g.resolution


def coverage_raster(old: OccupancyGrid, new: OccupancyGrid) -> tuple[NDArray[np.uint8], NDArray[np.float64], float]:
    """Both grids' observed cells on one grid at the coarser resolution, anchored at the
    plane origin: (labels (H, W) with 0 none, 1 only OLD, 2 only NEW, 3 both; origin (2,)
    plane coordinates of cell (0, 0)'s corner; resolution in metres).

    Raises `MapDiffError` when the grids lie on different ground planes (other `up` or
    in-plane axes): their areas cannot be compared cell by cell.
    """
    if not (np.allclose(old.up, new.up, atol=1e-6) and np.allclose(old.plane_axes, new.plane_axes, atol=1e-6)):
        raise MapDiffError("the maps' occupancy grids lie on different ground planes (other 'up' or plane axes)")
    res = max(old.resolution, new.resolution)
    ij_old = np.floor(_observed_plane_points(old) / res).astype(np.int64)
    ij_new = np.floor(_observed_plane_points(new) / res).astype(np.int64)
    both = np.concatenate([ij_old, ij_new])
    if len(both) == 0:
        return np.zeros((0, 0), np.uint8), np.zeros(2), res
    lo, hi = both.min(axis=0), both.max(axis=0)
    labels = np.zeros((int(hi[1] - lo[1]) + 1, int(hi[0] - lo[0]) + 1), np.uint8)
    labels[ij_old[:, 1] - lo[1], ij_old[:, 0] - lo[0]] |= 1
    labels[ij_new[:, 1] - lo[1], ij_new[:, 0] - lo[0]] |= 2
    return labels, lo.astype(np.float64) * res, res


def coverage_diff(old: OccupancyGrid, new: OccupancyGrid) -> CoverageDiff:
    """Observed area (m^2) of both grids on the common grid of `coverage_raster`."""
    labels, _, res = coverage_raster(old, new)
    area = res * res
    n = np.bincount(labels.ravel(), minlength=4) if labels.size else np.zeros(4, np.int64)
    return CoverageDiff(float(n[1] + n[3]) * area, float(n[2] + n[3]) * area, float(n[3]) * area,
                        float(n[1]) * area, float(n[2]) * area, res)


def _places_covered(src: TopoMap, dst: TopoMap, params: DiffParams) -> float:
    """Share of `src`'s keyframes with a `dst` keyframe within the place radius and angle."""
    if src.n_nodes == 0:
        return 1.0
    if dst.n_nodes == 0:
        return 0.0
    tree = cKDTree(dst.positions)
    cos_max = np.cos(np.radians(params.place_angle_deg))
    z_dst = dst.T_map_camera[:, :3, 2]
    hits = 0
    for i, near in enumerate(tree.query_ball_point(src.positions, r=params.place_radius_m)):
        if near and float(np.max(z_dst[near] @ src.T_map_camera[i, :3, 2])) >= cos_max:
            hits += 1
    return hits / src.n_nodes


def diff_maps(old: TopoMap, new: TopoMap, params: DiffParams | None = None) -> MapDiff:
    """Compare two maps (see the module docstring for what each category means)."""
    params = params or DiffParams()
    id_old, id_new = node_identities(old), node_identities(new)
    notes: list[str] = []
    if len(set(id_old)) < len(id_old) or len(set(id_new)) < len(id_new):
        notes.append("some keyframe images occur twice in one map; the first occurrence is matched")
    index_new: dict[str, int] = {}
    for j, h in enumerate(id_new):
        index_new.setdefault(h, j)
    kept: list[tuple[int, int]] = []
    matched_new: set[int] = set()
    for i, h in enumerate(id_old):
        jn = index_new.get(h)
        if jn is not None and jn not in matched_new:
            kept.append((i, jn))
            matched_new.add(jn)
    kept_arr = np.asarray(kept, dtype=np.int64).reshape(-1, 2)
    moved, dts, drs = [], [], []
    for k, (i, j) in enumerate(kept_arr):
        dt, dr = relative_pose_error(new.T_map_camera[j], old.T_map_camera[i])
        if dt > params.moved_m or dr > params.moved_deg:
            moved.append(k)
            dts.append(dt)
            drs.append(dr)
    kept_old = set(kept_arr[:, 0].tolist())
    retired = np.asarray([i for i in range(old.n_nodes) if i not in kept_old], dtype=np.int64)
    added = np.asarray([j for j in range(new.n_nodes) if j not in matched_new], dtype=np.int64)
    return MapDiff(
        kept=kept_arr, moved=np.asarray(moved, dtype=np.int64), moved_m=np.asarray(dts, dtype=np.float64),
        moved_deg=np.asarray(drs, dtype=np.float64), retired=retired, added=added,
        coverage=coverage_diff(old.grid, new.grid),
        old_places_kept=_places_covered(old, new, params), new_places_in_old=_places_covered(new, old, params),
        n_old=old.n_nodes, n_new=new.n_nodes, notes=tuple(notes),
    )
