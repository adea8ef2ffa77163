"""A building some time after it was mapped: a seeded transformation of a generated `World`.

`apply_change(world, params)` changes the world in place along the axes of
`WorldChangeParams` (`litevloc.base.params.world_change`), each from its own random stream
(`default_rng([params.seed, axis index])`), and returns the ground truth of what changed
(`ChangeTruth`, written beside a recording for benchmarks; the map and the localizer never
read it). The goal places stay those of the generated building.

* pictures: a share of the posters, prints and notice boards show another design or photograph;
* furniture: a share of the furniture and clutter (pillars excepted) moved along its wall,
  removed, or joined by a new piece of clutter in its room (kept clear of doors and goals);
* doors: leaves hung in a share of the doorways (`litevloc.sim.doors`);
* lighting: a `litevloc.sim.lighting.LightingChange` the textures are baked with;
* people: `litevloc.sim.people.Walkers` composited into every rendered frame.

What stays as generated: walls, floor plan, materials, every box and picture not listed in the
truth (a moved box keeps its texture: `World.box_source` maps each box to the generated one).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from litevloc.base.params.world_change import CHANGE_AXES, WorldChangeParams
from litevloc.sim.decor import change_pictures
from litevloc.sim.doors import hang_leaves, leaf_boxes
from litevloc.sim.elements import PictureKind
from litevloc.sim.furnish import box_faces, door_centres, make_clutter, slide_box
from litevloc.sim.lighting import draw_lighting
from litevloc.sim.people import Walkers

if TYPE_CHECKING:
    from litevloc.sim.world import World

GOAL_CLEAR_M = 0.8  # no changed box nearer a goal spot: the goal stays reachable
MOVE_SHARE, REMOVE_SHARE = 0.6, 0.2  # of the changed furniture; the rest gets a new piece beside it
PICTURE_KINDS: tuple[PictureKind, ...] = ("photo", "poster", "print", "notice")


@dataclass
class ChangeTruth:
    """What changed, per axis (JSON-ready lists of dicts); `levels` and `seed` as asked."""

    seed: int
    levels: dict[str, float]
    furniture: dict[str, list[dict[str, Any]]] = field(default_factory=dict)
    pictures: list[dict[str, Any]] = field(default_factory=list)
    doors: list[dict[str, Any]] = field(default_factory=list)
    lighting: dict[str, object] = field(default_factory=dict)
    people: dict[str, int] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


def _near_goal(box: np.ndarray, goals: np.ndarray) -> bool:
    if not len(goals):
        return False
    dx = np.maximum(np.maximum(box[0] - goals[:, 0], goals[:, 0] - box[2]), 0)
    dy = np.maximum(np.maximum(box[1] - goals[:, 1], goals[:, 1] - box[3]), 0)
    return bool(np.any(np.hypot(dx, dy) < GOAL_CLEAR_M))


def _change_furniture(world: World, fraction: float, rng: np.random.Generator) -> dict[str, list[dict[str, Any]]]:
    """Move, remove and add boxes (see module docstring); updates world.boxes, box_kinds, box_source."""
    boxes, kinds = world.boxes.copy(), list(world.box_kinds)
    goals = np.array([T[:2, 3] for T in world.goal_places.values()]).reshape(-1, 2)
    door_pts = door_centres(world.doors)
    keep = np.ones(len(boxes), bool)
    truth: dict[str, list[dict[str, Any]]] = {"moved": [], "removed": [], "added": []}
    add_in: list[int] = []
    for k in range(len(boxes)):
        if kinds[k] == "pillar" or rng.random() >= fraction:
            continue
        label = world.region_at(np.array([(boxes[k, 0] + boxes[k, 2]) / 2, (boxes[k, 1] + boxes[k, 3]) / 2]))
        reg = world.regions.get(label)
        u = rng.random()
        if reg is None:
            continue
        if u < MOVE_SHARE:
            before = boxes[k].copy()
            if slide_box(boxes, k, reg, door_pts, rng):
                if _near_goal(boxes[k], goals):
                    boxes[k] = before
                    continue
                truth["moved"].append({"box": k, "kind": kinds[k], "before": before.tolist(),
                                       "after": boxes[k].tolist()})
        elif u < MOVE_SHARE + REMOVE_SHARE:
            keep[k] = False
            truth["removed"].append({"box": k, "kind": kinds[k], "before": boxes[k].tolist()})
        else:
            add_in.append(label)
    source = np.nonzero(keep)[0]
    boxes, kinds = boxes[keep], [kinds[int(i)] for i in source]
    one = dataclasses.replace(world.spec, clutter_per_room=(1, 1))
    for label in add_in:
        new, new_kinds = make_clutter(one, {label: world.regions[label]}, world.doors, boxes, rng)
        if len(new) and not _near_goal(new[0], goals):
            boxes = np.concatenate([boxes, new[:1]])
            kinds.append(new_kinds[0])
            source = np.append(source, -1)
            truth["added"].append({"kind": new_kinds[0], "after": new[0].tolist()})
    world.boxes, world.box_kinds, world.box_source = boxes, kinds, source.astype(np.intp)
    return truth


def _hang_doors(world: World, fraction: float, rng: np.random.Generator) -> list[dict[str, Any]]:
    rooms = {k for k, r in world.regions.items() if r.kind == "room"}
    leaves = hang_leaves(world.doors, rooms, set(world.regions), world.boxes, world.region_at, fraction,
                         world.wall_height, rng)
    if leaves:
        world.boxes = np.concatenate([world.boxes, leaf_boxes(leaves)])
        world.box_kinds = world.box_kinds + ["door"] * len(leaves)
        world.box_source = np.append(world.box_source, np.full(len(leaves), -1, np.intp))
        world.closed_doors = {lf.door for lf in leaves if lf.closed}
    return [{"door": lf.door, "state": "closed" if lf.closed else "open", "regions": list(world.doors[lf.door][:2]),
             "box": list(lf.box)} for lf in leaves]


def apply_change(world: World, params: WorldChangeParams) -> ChangeTruth:
    """Change `world` in place (see module docstring); nothing happens at level 0 on every axis."""
    truth = ChangeTruth(params.seed, params.levels())
    if params.unchanged:
        return truth

    def stream(axis: str) -> np.random.Generator:
        return np.random.default_rng([params.seed, 100 + CHANGE_AXES.index(axis)])

    if params.pictures > 0:
        world.posters, replaced = change_pictures(world.posters, stream("pictures"), params.pictures, PICTURE_KINDS)
        truth.pictures = [{"index": i, "kind": world.posters[i].kind, "face": world.posters[i].face} for i in replaced]
    if params.furniture > 0:
        truth.furniture = _change_furniture(world, params.furniture, stream("furniture"))
    if params.doors > 0:
        truth.doors = _hang_doors(world, params.doors, stream("doors"))
    if params.lighting > 0:
        world.lighting = draw_lighting(sorted(world.regions), params.lighting, stream("lighting"))
        truth.lighting = world.lighting.summary()
    if params.people > 0:
        world.people = Walkers(params.people, params.seed)
        truth.people = {"count": params.people, "seed": params.seed}
    if params.furniture > 0 or params.doors > 0:
        world.faces = [f for f in world.faces if f.kind != "box"] + box_faces(world.boxes)
        for name in ("wall_segments", "clearance_grid"):  # cached for the generated building
            world.__dict__.pop(name, None)
    return truth
