"""How much of a simulated building a map covers, measured against the building itself.

A map's own coverage figure (`map build`: the share of the candidate views its keyframes
cover) says nothing about rooms the mapping pass never saw. Here the reference is the
building's free space: every cell of the world's 0.1 m clearance grid where the robot's
centre can stand (farther than its radius from every wall and box) in the building's main
free space. A cell is covered when the map's occupancy grid knows it as free
(`pipelines.topomap.openings.mapped_free`); the map frame of a map built from the simulator
is the world frame.
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from litevloc.base.params.navigation import OpeningParams
from litevloc.pipelines.topomap.openings import mapped_free
from litevloc.pipelines.topomap.types import OccupancyGrid
from litevloc.sim.world import World


def free_space(world: World, radius: float) -> NDArray[np.bool_]:
    """(H, W) cells of the world's clearance grid where a robot of `radius` (m) can stand, in
    the largest connected such space."""
    dist, _res = world.clearance_grid
    free = (dist > radius).astype(np.uint8)
    n, comp = cv2.connectedComponents(free, connectivity=8)
    if n <= 1:
        return np.zeros(dist.shape, bool)
    return np.asarray(comp == 1 + int(np.argmax(np.bincount(comp.ravel())[1:])))


def map_coverage(world: World, grid: OccupancyGrid, keyframe_xy: NDArray[np.floating], radius: float,
                 params: OpeningParams = OpeningParams()) -> dict[str, Any]:
    """Share of the building's free space the map knows (`free_space_coverage`, 0-1), per region
    (`regions`: name -> share), the rooms with at least half of their free space covered
    (`rooms_mapped`), the rooms a keyframe stands in (`rooms_entered`; `keyframe_xy` (N, 2)
    keyframe camera positions, world frame) and the rooms in the building (`rooms`)."""
    dist, res = world.clearance_grid
    free = free_space(world, radius)
    ii, jj = np.nonzero(free)
    xy = (np.stack([jj, ii], 1) + 0.5) * res
    known = mapped_free(grid, params)
    ij = grid.cell_of(grid.to_plane(np.concatenate([xy, np.zeros((len(xy), 1))], 1)))
    H, W = known.shape
    inside = (ij[:, 0] >= 0) & (ij[:, 0] < H) & (ij[:, 1] >= 0) & (ij[:, 1] < W)
    covered = np.zeros(len(xy), bool)
    covered[inside] = known[ij[inside, 0], ij[inside, 1]]
    lab = cv2.resize(world.labels.astype(np.float32), (dist.shape[1], dist.shape[0]),
                     interpolation=cv2.INTER_NEAREST).astype(np.int32)[ii, jj]
    regions = {r.name: round(float(covered[lab == k].mean()), 3) if np.any(lab == k) else 0.0
               for k, r in world.regions.items()}
    kf = np.asarray(keyframe_xy, np.float64).reshape(-1, 2)
    entered = {world.regions[label].name for label in (world.region_at(p) for p in kf) if label in world.regions}
    rooms = sorted(r.name for r in world.regions.values() if r.kind == "room")
    return {"free_space_coverage": round(float(covered.mean()) if len(covered) else 0.0, 4),
            "regions": regions, "rooms": len(rooms),
            "rooms_mapped": sum(regions[r] >= 0.5 for r in rooms),
            "rooms_entered": sum(r in entered for r in rooms),
            "rooms_not_entered": [r for r in rooms if r not in entered]}
