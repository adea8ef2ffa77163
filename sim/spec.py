"""World files: `WorldSpec` (a building generator's parameters) loaded strictly from YAML.

Shipped world files live in `config/worlds/<name>.yaml`; any other YAML path works too.
`litevloc.sim.world.World(spec)` generates the building; everything random in it is drawn
from `spec.seed` (`--world-seed` overrides it), so a spec and a seed give the same building
on every machine.
"""

from __future__ import annotations

import importlib.util
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from litevloc.base.loader import ConfigError, from_mapping, load_yaml
from litevloc.base.params.world_change import WorldChangeParams


def _worlds_dir() -> Path:
    # the world files are data of the config package: locate it without importing it (sim never imports config)
    spec = importlib.util.find_spec("litevloc.config")
    if spec is None or not spec.submodule_search_locations:
        raise ConfigError("the litevloc.config package (with config/worlds/*.yaml) is not installed")
    return Path(next(iter(spec.submodule_search_locations))).resolve() / "worlds"


@dataclass(frozen=True)
class WorldSpec:
    """Description of a procedural building (all lengths metres).

    layout "grid": `rows` x `cols` rooms of `room_size` (x, y); with `corridor_width` > 0
    a corridor runs between consecutive rows of rooms, joined by one along the east side.
    layout "loop": a ring corridor of outer size `loop_size` and width `corridor_width`
    around a block divided into `rows` x `cols` rooms (a long loop for drift tests).
    """

    name: str
    seed: int = 0
    layout: Literal["grid", "loop"] = "grid"
    rows: int = 2
    cols: int = 2
    room_size: tuple[float, float] = (5.0, 4.0)
    # Grid layout: each column's width and each row's depth is room_size times a factor drawn
    # from [1 - room_size_jitter, 1 + room_size_jitter] with the seed (0: every room the same size).
    room_size_jitter: float = 0.15
    corridor_width: float = 0.0
    loop_size: tuple[float, float] = (60.0, 40.0)
    wall_height: float = 2.6
    cell: float = 0.25
    door_width: float = 1.0
    extra_door_prob: float = 0.3
    furniture_per_room: tuple[int, int] = (2, 5)
    # Small free-standing things per room (bins, plant pots, stools, boxes; 0.3-0.6 m across,
    # 0.35-1.1 m high), kept 1.3 m from doors and 0.8 m from the goal spots.
    clutter_per_room: tuple[int, int] = (1, 3)
    posters_per_room: tuple[int, int] = (1, 3)
    texture_poor_fraction: float = 0.25
    repetitive_fraction: float = 0.25
    # "varied": every picture is generated for this building (posters, framed prints, signs,
    # room-number plates, notice boards, per-room furniture colours); none repeats unless
    # repeated_pictures asks. "aliased": the pictures are the 11 photographs and the wall
    # materials 3 images of scikit-image's data folder, as in the first simulator (a 15-room
    # floor hangs each photograph about three times); no signs, plates or notice boards.
    appearance: Literal["varied", "aliased"] = "varied"
    # Share of the pictures (varied appearance) that show the same picture as an earlier one
    # in the building (the same print bought twice): the hard case for goal images.
    repeated_pictures: float = 0.0
    # Goal places: "person" (a seeded free spot in the room, facing into it: `litevloc.sim.goals`),
    # "poster" (the first simulator's: ~2.5 m in front of a poster, facing it).
    goal_rule: Literal["person", "poster"] = "person"
    texels_per_m: float = 64.0
    # A changed version of the same world (for map update tests): with change_seed >= 0, after
    # generation a `change_fraction` of the posters get another picture and of the furniture
    # (pillars excepted) slides 0.5-1.5 m along its wall where the room allows; < 0: as generated.
    change_seed: int = -1
    change_fraction: float = 0.5
    # The building some time after it was mapped, graded per axis (`litevloc.sim.change`);
    # all levels 0: as generated.
    change: WorldChangeParams = field(default_factory=WorldChangeParams)

    def __post_init__(self) -> None:
        if not self.name:
            raise ValueError("name must not be empty")
        if self.rows < 1 or self.cols < 1 or self.rows * self.cols > 400:
            raise ValueError(
                f"rows, cols must be >= 1 with at most 400 rooms, got {self.rows}x{self.cols}"
            )
        if not (0.05 <= self.cell <= 1.0):
            raise ValueError(f"cell must be in [0.05, 1] m, got {self.cell}")
        if min(self.room_size) < 2.0 or max(self.room_size) > 50:
            raise ValueError(f"room_size must be in [2, 50] m, got {self.room_size}")
        if not (0 <= self.room_size_jitter <= 0.4):
            raise ValueError(f"room_size_jitter must be in [0, 0.4], got {self.room_size_jitter}")
        if self.room_size_jitter and min(self.room_size) * (1 - self.room_size_jitter) < 2.0:
            raise ValueError(f"room_size {self.room_size} with room_size_jitter {self.room_size_jitter} "
                             "can make a room narrower than 2 m")
        if self.corridor_width != 0 and not (1.0 <= self.corridor_width <= 10):
            raise ValueError(f"corridor_width must be 0 or in [1, 10] m, got {self.corridor_width}")
        if self.layout == "loop":
            if self.corridor_width == 0:
                raise ValueError("layout 'loop' needs corridor_width > 0")
            if min(self.loop_size) < 2 * self.corridor_width + 4 or max(self.loop_size) > 200:
                raise ValueError(
                    f"loop_size {self.loop_size} too small for the corridor, or > 200 m"
                )
        if not (1.5 <= self.wall_height <= 6):
            raise ValueError(f"wall_height must be in [1.5, 6] m, got {self.wall_height}")
        if not (0.6 <= self.door_width <= 3):
            raise ValueError(f"door_width must be in [0.6, 3] m, got {self.door_width}")
        for name in ("extra_door_prob", "texture_poor_fraction", "repetitive_fraction", "change_fraction",
                     "repeated_pictures"):
            v = getattr(self, name)
            if not (0 <= v <= 1):
                raise ValueError(f"{name} must be in [0, 1], got {v}")
        for name in ("furniture_per_room", "posters_per_room", "clutter_per_room"):
            lo, hi = getattr(self, name)
            if lo < 0 or hi < lo or hi > 20:
                raise ValueError(
                    f"{name} must be [min, max] with 0 <= min <= max <= 20, got {(lo, hi)}"
                )
        if not (16 <= self.texels_per_m <= 256):
            raise ValueError(f"texels_per_m must be in [16, 256], got {self.texels_per_m}")


def world_names() -> list[str]:
    """Names of the shipped worlds (file stems in config/worlds)."""
    return sorted(p.stem for p in _worlds_dir().glob("*.yaml"))


def resolve_world_path(name_or_path: str | Path) -> Path:
    """A shipped world name ("office") or a path to a YAML file -> existing path."""
    p = Path(name_or_path)
    if p.suffix in (".yaml", ".yml"):
        if p.is_file():
            return p
        shipped = _worlds_dir() / p.name
        if p.parent == Path(".") and shipped.is_file():
            return shipped
        raise ConfigError(f"world file not found: {p}")
    shipped = _worlds_dir() / f"{name_or_path}.yaml"
    if shipped.is_file():
        return shipped
    raise ConfigError(
        f"unknown world {str(name_or_path)!r}: not a file, and shipped worlds are {world_names()}"
    )


def load_world_spec(name_or_path: str | Path) -> WorldSpec:
    """The spec of a shipped world name or a YAML path (unknown keys, bad types: ConfigError)."""
    path = resolve_world_path(name_or_path)
    return from_mapping(WorldSpec, load_yaml(path), str(path))
