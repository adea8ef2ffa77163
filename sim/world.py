"""A generated building: floor plan, furniture, wall pictures and goal places, and queries.

A world is generated from a `WorldSpec` (`litevloc.sim.spec`, loaded strictly from YAML in
`config/worlds/<name>.yaml`) and the spec's seed:

* `layout`: rooms and corridors on a label grid, doors (a random spanning tree of the
  region graph plus extra doors), wall faces;
* `furnish`: furniture against the walls and clutter in the rooms (boxes);
* `decor`: wall materials and pictures (posters; with the varied appearance also
  room-number plates, notice boards and corridor signs, each picture its own design);
* `goals`: one goal place per room (the goal-image rule).

World frame: z up, metres; the floor is z = 0 and the ceiling z = `wall_height`.

Geometry handed to the renderer:

* `faces`: vertical rectangles (`litevloc.sim.elements.Face`: one per side of each wall
  segment, four per box);
* `boxes`: (N, 5) x0, y0, x1, y1, height; `box_kinds` names each (cabinet, shelf, desk,
  pillar; clutter: bin, plant, stool, crate).

Textures (`litevloc.sim.textures`) are baked once per world by the renderer.

Random streams: the main one (`default_rng(seed)`) draws doors, furniture, materials and
where posters hang, in the first simulator's order, so a world with `appearance: aliased`,
no clutter, no room-size jitter and `goal_rule: poster` is that simulator's world exactly.
Room sizes, clutter, picture designs and goal places each have their own stream
(`default_rng([seed, k])`), so switching one of them changes nothing else.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from litevloc.sim.change import ChangeTruth, apply_change
from litevloc.sim.decor import assign_materials, change_pictures, decorate, hang_posters
from litevloc.sim.elements import Face, Poster, Region
from litevloc.sim.furnish import box_faces, legacy_kind, make_clutter, make_furniture, slide_furniture
from litevloc.sim.goals import GoalView, person_goals, poster_goals
from litevloc.sim.layout import make_floor_plan
from litevloc.sim.lighting import LightingChange
from litevloc.sim.people import Walkers
from litevloc.sim.spec import WorldSpec, load_world_spec


@dataclass(frozen=True)
class GeneratedParts:
    """Faces, boxes (N, 5) and box kinds of a building as generated, before any change."""

    faces: list[Face]
    boxes: NDArray[np.float64]
    box_kinds: list[str]


def load_world(name_or_path: str | Path, seed: int | None = None, **overrides: object) -> World:
    """Load a world by shipped name or YAML path; `seed` overrides the spec's seed and
    `overrides` any other spec field (e.g. `appearance="aliased"`)."""
    spec = load_world_spec(name_or_path)
    changes = {**overrides, **({} if seed is None else {"seed": int(seed)})}
    if changes:
        spec = WorldSpec(**{**spec.__dict__, **changes})
    return World(spec)


class World:
    """Geometry and appearance of one generated building (see module docstring)."""

    def __init__(self, spec: WorldSpec) -> None:
        self.spec = spec
        self.rng = np.random.default_rng(spec.seed)
        self.wall_height = spec.wall_height
        plan = make_floor_plan(spec, self.rng)
        self.labels = plan.labels
        self.regions: dict[int, Region] = plan.regions
        self.doors = plan.doors
        furniture = make_furniture(spec, self.regions, self.doors, self.rng)
        clutter, clutter_kinds = make_clutter(spec, self.regions, self.doors, furniture,
                                              np.random.default_rng([spec.seed, 2]))
        self.boxes = np.concatenate([furniture, clutter])
        self.box_kinds = [legacy_kind(h, spec.wall_height) for h in furniture[:, 4]] + clutter_kinds
        self.faces = plan.faces + box_faces(self.boxes)
        assign_materials(spec, self.regions, self.rng)
        self.posters: list[Poster] = hang_posters(spec, self.regions, self.faces, self.wall_height, self.rng)
        if spec.appearance == "varied":
            self.posters = decorate(spec, self.regions, self.faces, self.doors, self.posters, self.wall_height)
        # goal spots come from the building as generated: a changed version keeps them (map update)
        self.goal_views: dict[str, GoalView] = (
            person_goals(self, spec.seed) if spec.goal_rule == "person"
            else poster_goals(self, self.faces, self.posters, spec.seed))
        self.changes: dict[str, int] = {"posters": 0, "furniture": 0}
        # the building as generated: a changed one bakes these first, so what did not change looks the same
        self.generated = GeneratedParts(list(self.faces), self.boxes.copy(), list(self.box_kinds))
        # the generated box each box is (-1: one a change added)
        self.box_source: NDArray[np.intp] = np.arange(len(self.boxes), dtype=np.intp)
        self.closed_doors: set[int] = set()  # indices into doors that a closed leaf blocks
        self.lighting: LightingChange | None = None
        self.people: Walkers | None = None
        if spec.change_seed >= 0:
            self._apply_changes(np.random.default_rng(spec.change_seed), spec.change_fraction)
        # where the robot stands for each room's robot-camera goal image (4x4 T_world_base)
        self.goal_places: dict[str, NDArray[np.float64]] = {k: v.T_world_base for k, v in self.goal_views.items()}
        self.change_truth: ChangeTruth = apply_change(self, spec.change)

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """x0, y0, x1, y1 of the label grid (metres)."""
        c = self.spec.cell
        return 0.0, 0.0, self.labels.shape[1] * c, self.labels.shape[0] * c

    def _apply_changes(self, rng: np.random.Generator, fraction: float) -> None:
        """Re-picture posters and slide furniture along its wall (see `WorldSpec.change_seed`)."""
        self.posters, pictures = change_pictures(self.posters, rng, fraction)
        self.changes["posters"] = len(pictures)
        centres = [self.region_at(np.array([(b[0] + b[2]) / 2, (b[1] + b[3]) / 2])) for b in self.boxes]
        self.boxes, self.changes["furniture"] = slide_furniture(self.boxes, self.box_kinds, self.doors,
                                                                self.regions, centres, rng, fraction)
        self.faces = [f for f in self.faces if f.kind != "box"] + box_faces(self.boxes)
        for name in ("wall_segments", "clearance_grid"):  # computed for the goal spots before the changes
            self.__dict__.pop(name, None)

    # ----------------------------------------------------------------- queries
    @cached_property
    def wall_segments(self) -> NDArray[np.float64]:
        """(N, 4) x0, y0, x1, y1 of every wall face and box face (for collisions/plots)."""
        segs = []
        for f in self.faces:
            if f.axis == 0:
                segs.append((f.c, f.lo, f.c, f.hi))
            else:
                segs.append((f.lo, f.c, f.hi, f.c))
        return np.array(segs, dtype=np.float64).reshape(-1, 4)

    def region_at(self, xy: NDArray[np.floating]) -> int:
        """Label of the region containing point xy (0 = solid / outside)."""
        c = self.spec.cell
        j, i = int(np.floor(xy[0] / c)), int(np.floor(xy[1] / c))
        if 0 <= i < self.labels.shape[0] and 0 <= j < self.labels.shape[1]:
            return int(self.labels[i, j])
        return 0

    def clearance(self, xy: NDArray[np.floating]) -> NDArray[np.float64]:
        """Distance (m) from each of (N, 2) points to the nearest wall or box face; 0 outside."""
        P = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        S = self.wall_segments
        a, b = S[None, :, :2], S[None, :, 2:]
        ab = b - a
        t = np.clip(
            np.sum((P[:, None, :] - a) * ab, -1) / np.maximum(np.sum(ab * ab, -1), 1e-12), 0, 1
        )
        d = np.linalg.norm(P[:, None, :] - (a + t[..., None] * ab), axis=-1).min(axis=1)
        inside = np.array([self.region_at(p) > 0 for p in P])
        if len(self.boxes):
            B = self.boxes
            in_box = (
                (P[:, None, 0] > B[None, :, 0])
                & (P[:, None, 0] < B[None, :, 2])
                & (P[:, None, 1] > B[None, :, 1])
                & (P[:, None, 1] < B[None, :, 3])
            ).any(axis=1)
            inside &= ~in_box
        return np.where(inside, d, 0.0)

    def is_free(self, xy: NDArray[np.floating], radius: float) -> bool:
        """True if a disc of `radius` metres at xy (world) touches no wall or box."""
        dist, res = self.clearance_grid
        i, j = int(xy[1] / res), int(xy[0] / res)
        if 0 <= i < dist.shape[0] and 0 <= j < dist.shape[1] and dist[i, j] > radius + 2.5 * res:
            return (
                True  # far from everything on the grid (grid error < 2 cells): skip the exact test
            )
        return bool(self.clearance(np.asarray(xy, dtype=np.float64)[:2])[0] > radius)

    @cached_property
    def clearance_grid(self) -> tuple[NDArray[np.float32], float]:
        """(H, W) clearance map (m) on a 0.1 m grid over `bounds`, and its resolution."""
        res = 0.1
        x0, y0, x1, y1 = self.bounds
        W, H = int(np.ceil((x1 - x0) / res)), int(np.ceil((y1 - y0) / res))
        occ = np.full((H, W), 255, np.uint8)
        lab_up = cv2.resize(self.labels.astype(np.float32), (W, H), interpolation=cv2.INTER_NEAREST)
        occ[lab_up == 0] = 0
        for sx0, sy0, sx1, sy1 in self.wall_segments:
            p0 = (round(sx0 / res), round(sy0 / res))
            p1 = (round(sx1 / res), round(sy1 / res))
            cv2.line(occ, p0, p1, 0, 1)
        for bx0, by0, bx1, by1, _ in self.boxes:
            cv2.rectangle(
                occ,
                (int(bx0 / res), int(by0 / res)),
                (int(np.ceil(bx1 / res)), int(np.ceil(by1 / res))),
                0,
                -1,
            )
        dist = cv2.distanceTransform(occ, cv2.DIST_L2, 5).astype(np.float32) * res
        return dist, res

    def room_centre(self, label: int) -> NDArray[np.float64]:
        """The point of a region farthest from walls and boxes."""
        dist, res = self.clearance_grid
        lab_up = cv2.resize(
            self.labels.astype(np.float32),
            (dist.shape[1], dist.shape[0]),
            interpolation=cv2.INTER_NEAREST,
        )
        d = np.where(lab_up == label, dist, -1)
        i, j = np.unravel_index(int(np.argmax(d)), d.shape)
        return np.array([(j + 0.5) * res, (i + 0.5) * res])

    def summary(self) -> dict[str, object]:
        x0, y0, x1, y1 = self.bounds
        return {
            "name": self.spec.name,
            "seed": self.spec.seed,
            "appearance": self.spec.appearance,
            "goal_rule": self.spec.goal_rule,
            "size_m": [x1 - x0, y1 - y0],
            "regions": len(self.regions),
            "rooms": sum(r.kind == "room" for r in self.regions.values()),
            "doors": len(self.doors),
            "faces": len(self.faces),
            "boxes": len(self.boxes),
            "posters": len(self.posters),
            "goal_places": sorted(self.goal_places),
        }

