"""How a simulated building changed since it was mapped: the `change:` block of a world file.

Each axis has a level; 0 everywhere is the building as generated (bit-identical). The change
is a seeded transformation of the generated building (`litevloc.sim.change`), drawn from
`seed` with one stream per axis, so raising one axis's level changes nothing on the others.
`MIXES` are named combinations fixed before any result (`--change months_later`).
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace
from typing import Literal

from litevloc.base.errors import LiteVLocError
from litevloc.base.settings import Settings, setting

ChangeAxis = Literal["lighting", "furniture", "pictures", "people", "doors"]
CHANGE_AXES: tuple[ChangeAxis, ...] = ("lighting", "furniture", "pictures", "people", "doors")


class ChangeSpecError(LiteVLocError, ValueError):
    """A `--change AXIS=LEVEL` item names no axis or mix, or its level is out of range."""


@dataclass(frozen=True)
class WorldChangeParams(Settings):
    """Levels of change per axis (0: unchanged) and the seed they are drawn from."""

    seed: int = setting(0, "seed of the change (one stream per axis)", low=0)
    lighting: float = setting(
        0.0, "lighting change: daylight of another hour (sun direction turned by up to 90 deg x level, "
        "strength 0.35 x level), lamps switched in level/2 of the regions, exposure off by up to "
        "0.6 EV x level", low=0, high=1)
    furniture: float = setting(
        0.0, "share of the furniture and clutter changed: of those, 60 % moved 0.5-1.5 m along "
        "their wall, 20 % removed, and as many new pieces of clutter added as 20 % of them", low=0, high=1)
    pictures: float = setting(
        0.0, "share of the posters, prints and notice boards that show another picture "
        "(room-number plates and signs stay)", low=0, high=1)
    people: int = setting(
        0, "people walking across the camera's view (visual occluders with depth; the robot's "
        "collisions and route ignore them)", low=0, high=6)
    doors: float = setting(
        0.0, "share of the doorways that get a door leaf: closed where the building stays "
        "connected without that doorway (half of those), else standing open at 90 deg", low=0, high=1)

    @property
    def unchanged(self) -> bool:
        """True when every level is 0 (the building as generated)."""
        return all(getattr(self, a) == 0 for a in CHANGE_AXES)

    def levels(self) -> dict[str, float]:
        """{axis: level} of every axis."""
        return {a: float(getattr(self, a)) for a in CHANGE_AXES}


# Named mixes, fixed before any result: "months later" is the example of a building a
# few months after it was mapped.
MIXES: dict[str, WorldChangeParams] = {
    "months_later": WorldChangeParams(seed=0, lighting=0.5, furniture=0.3, pictures=0.3, people=2),
}


def parse_change(items: list[str], base: WorldChangeParams | None = None) -> WorldChangeParams:
    """`["furniture=0.3", "people=2", "months_later"]` -> params: a mix name sets its levels, then
    `AXIS=LEVEL` items (and `seed=N`) override them in order. ChangeSpecError names a bad item."""
    out = base or WorldChangeParams()
    names = {f.name for f in fields(WorldChangeParams)}
    for item in items:
        if "=" not in item:
            if item not in MIXES:
                raise ChangeSpecError(f"--change {item!r}: not AXIS=LEVEL and not a named mix {sorted(MIXES)}")
            mix = MIXES[item]
            out = replace(out, **{a: getattr(mix, a) for a in CHANGE_AXES})
            continue
        key, raw = (s.strip() for s in item.split("=", 1))
        if key not in names:
            raise ChangeSpecError(f"--change {item!r}: unknown axis {key!r}; axes are {list(CHANGE_AXES)} (and seed)")
        try:
            value: float | int = int(raw) if key in ("people", "seed") else float(raw)
        except ValueError:
            kind = "an integer" if key in ("people", "seed") else "a number"
            raise ChangeSpecError(f"--change {item!r}: level must be {kind}, got {raw!r}") from None
        try:
            out = replace(out, **{key: value})  # type: ignore[arg-type]
        except ValueError as exc:
            raise ChangeSpecError(f"--change {item!r}: {exc}") from None
    return out
