"""What hangs on the walls: wall materials per region and the pictures (`Poster`s).

The building's main random stream chooses the materials and where posters hang (as the
first simulator did, so an "aliased" and a "varied" building of the same seed have the same
posters in the same places). With the varied appearance every poster then gets a design of
its own, drawn from a separate stream, and the walls get what a real building has besides:
room-number plates beside doors, notice boards in rooms and corridors, direction signs in
corridors. Nothing here draws pixels (`litevloc.sim.pictures` does).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

from litevloc.sim.elements import Face, PictureKind, Poster, Region, s_increasing
from litevloc.sim.layout import Door
from litevloc.sim.spec import WorldSpec

POSTER_IMAGES = (
    "astronaut.png",
    "rocket.jpg",
    "hubble_deep_field.jpg",
    "camera.png",
    "chelsea.png",
    "coffee.png",
    "coins.png",
    "clock_motion.png",
    "text.png",
    "retina.jpg",
    "cell.png",
)
ROOM_NAMES = ("Office", "Meeting", "Lab", "Kitchen", "Store", "Studio", "Library", "Workshop", "Print",
              "Quiet room", "Archive", "Lounge", "Server", "Mail", "Copy")
PLATE_SIZE_M = (0.26, 0.16)
PLATE_Z_M = 1.45  # lower edge of a door plate
PLATE_FROM_DOOR_M = 0.12


def assign_materials(spec: WorldSpec, regions: dict[int, Region], rng: np.random.Generator) -> None:
    """Wall material per region: `texture_poor_fraction` of the rooms plain painted,
    `repetitive_fraction` brick, the rest drawn; corridors painted."""
    rooms = [r for r in regions.values() if r.kind == "room"]
    order = rng.permutation(len(rooms))
    n_poor = round(spec.texture_poor_fraction * len(rooms))
    n_rep = round(spec.repetitive_fraction * len(rooms))
    for rank, idx in enumerate(order):
        r = rooms[int(idx)]
        if rank < n_poor:
            r.material = "painted"
        elif rank < n_poor + n_rep:
            r.material = "brick"
        else:
            r.material = str(rng.choice(["plaster", "wallpaper", "panel", "brick"]))
    for r in regions.values():
        if r.kind == "corridor":
            r.material = "painted"


def hang_posters(spec: WorldSpec, regions: dict[int, Region], faces: list[Face], wall_height: float,
                 rng: np.random.Generator) -> list[Poster]:
    """Posters on the wall faces of every region (texture-poor rooms: at most one; corridors:
    one per ~6 m of wall), each a photograph of `POSTER_IMAGES` (drawn from `rng`)."""
    posters: list[Poster] = []
    faces_by_region: dict[int, list[int]] = {}
    for i, f in enumerate(faces):
        if f.kind == "wall" and f.hi - f.lo >= 1.6:
            faces_by_region.setdefault(f.region, []).append(i)
    for r in regions.values():
        cand = faces_by_region.get(r.label, [])
        if not cand:
            continue
        lo_n, hi_n = spec.posters_per_room
        n = int(rng.integers(lo_n, hi_n + 1))
        if r.material == "painted" and r.kind == "room":
            n = min(n, 1)
        if r.kind == "corridor":
            n = max(1, int(sum(faces[i].hi - faces[i].lo for i in cand) / 6.0))
        for _ in range(n):
            fi = int(rng.choice(cand))
            f = faces[fi]
            w = rng.uniform(0.6, min(1.4, f.hi - f.lo - 0.4))
            hgt = w * rng.uniform(0.6, 1.0)
            s0 = rng.uniform(0.2, f.hi - f.lo - w - 0.2)
            z0 = rng.uniform(0.9, max(0.95, min(2.0, wall_height - 0.2) - hgt))
            if any(p.face == fi and p.s0 < s0 + w + 0.1 and s0 < p.s0 + p.width + 0.1 for p in posters):
                continue
            posters.append(Poster(fi, s0, z0, w, hgt, str(rng.choice(POSTER_IMAGES))))
    return posters


class _Designs:
    """Designs handed out once each; a `repeated` share of the requests for copyable pictures
    get an earlier one again: its kind, design and size (m), a copy of the same print."""

    def __init__(self, rng: np.random.Generator, repeated: float) -> None:
        self.rng, self.repeated = rng, repeated
        self.given: list[tuple[PictureKind, int, float, float]] = []
        self._used: set[int] = set()

    def next(self, kind: PictureKind, width: float, height: float, copyable: bool = True,
             copy_fits: Callable[[float, float], bool] = lambda w, h: True) -> tuple[PictureKind, int, float, float]:
        """(kind, design, width, height) for a picture of `kind` and size (m): a copy of an
        earlier copyable one (where `copy_fits` its size), else a new design."""
        if copyable and self.given and self.rng.random() < self.repeated:
            copy = self.given[int(self.rng.integers(len(self.given)))]
            if copy_fits(copy[2], copy[3]):
                return copy
        d = int(self.rng.integers(1, 2**31 - 1))
        while d in self._used:
            d = int(self.rng.integers(1, 2**31 - 1))
        self._used.add(d)
        if copyable:
            self.given.append((kind, d, width, height))
        return kind, d, width, height


def number_rooms(regions: dict[int, Region], rng: np.random.Generator) -> None:
    """Room numbers "F.NN" (F: the building's floor, drawn) and a name for about half the rooms."""
    floor = int(rng.integers(0, 5))
    names = list(ROOM_NAMES)
    rng.shuffle(names)
    k = 0
    for r in regions.values():
        if r.kind != "room":
            continue
        k += 1
        r.number = f"{floor}.{k:02d}"
        if rng.random() < 0.5 and names:
            r.number += f" {names.pop()}"


def vary_posters(posters: list[Poster], regions: dict[int, Region], faces: list[Face], designs: _Designs,
                 rng: np.random.Generator) -> list[Poster]:
    """Each photograph poster becomes a generated picture of its own: a poster (title and
    text) or, in rooms, sometimes a framed print (no text)."""
    out: list[Poster] = []
    for p in posters:
        reg = regions.get(faces[p.face].region)
        want: PictureKind = "print" if reg is not None and reg.kind == "room" and rng.random() < 0.4 else "poster"
        f = faces[p.face]

        def fits(w: float, h: float, p: Poster = p, f: Face = f) -> bool:
            return p.s0 + w <= f.hi - f.lo - 0.1 and p.z0 + h <= f.height - 0.1 and _free_on_face(
                [q for q in out if q.face == p.face], p.face, p.s0, w, p.z0, h)

        kind, design, w, h = designs.next(want, p.width, p.height, copy_fits=fits)
        out.append(dataclasses.replace(p, image="", kind=kind, design=design, width=w, height=h))
    return out


def _free_on_face(posters: list[Poster], fi: int, s0: float, width: float, z0: float, height: float) -> bool:
    return not any(p.face == fi and p.s0 < s0 + width + 0.08 and s0 < p.s0 + p.width + 0.08
                   and p.z0 < z0 + height + 0.08 and z0 < p.z0 + p.height + 0.08 for p in posters)


def door_faces(door: Door, region: int, faces: list[Face]) -> list[tuple[int, float]]:
    """Wall faces of `region` that end at the door's edge: (face index, s of the door-side end)."""
    _a, _b, x0, y0, x1, y1 = door
    axis = 0 if x0 == x1 else 1  # a door in a plane x = c is on faces of axis 0
    c, lo, hi = (x0, y0, y1) if axis == 0 else (y0, x0, x1)
    out = []
    for i, f in enumerate(faces):
        if f.kind != "wall" or f.region != region or f.axis != axis or abs(f.c - c) > 1e-6:
            continue
        for end, world_end in ((f.hi, lo), (f.lo, hi)):
            if abs(end - world_end) < 1e-6:
                s_end = (end - f.lo) if s_increasing(f) else (f.hi - end)
                out.append((i, s_end))
    return out


def add_plates(doors: list[Door], regions: dict[int, Region], faces: list[Face], posters: list[Poster],
               designs: _Designs, rng: np.random.Generator) -> None:
    """A number plate beside each door, on both sides, showing the room it leads into; a room
    with several doors has them lettered ("1.04" -> "1.04a", "1.04b"), so no two plates match."""
    w, h = PLATE_SIZE_M
    doors_of: dict[int, list[int]] = {}
    for a, b, *_ in doors:
        doors_of.setdefault(a, []).append(b)
        doors_of.setdefault(b, []).append(a)

    def door_letter(here: int, there: int) -> str:
        others = doors_of[there]
        return "" if len(others) == 1 else "abcdefghij"[others.index(here) % 10]

    for door in doors:
        a, b = door[0], door[1]
        for here, there in ((a, b), (b, a)):
            if regions[there].kind != "room":
                continue
            spots = door_faces(door, here, faces)
            rng.shuffle(spots)
            for fi, s_end in spots:
                length = faces[fi].hi - faces[fi].lo
                if length < w + 2 * PLATE_FROM_DOOR_M:
                    continue
                s0 = s_end - PLATE_FROM_DOOR_M - w if s_end > length / 2 else s_end + PLATE_FROM_DOOR_M
                if _free_on_face(posters, fi, s0, w, PLATE_Z_M, h):
                    design = designs.next("plate", w, h, copyable=False)[1]
                    posters.append(Poster(fi, s0, PLATE_Z_M, w, h, "", "plate", design,
                                          (regions[there].number + door_letter(here, there),)))
                    break


def add_boards_and_signs(regions: dict[int, Region], faces: list[Face], posters: list[Poster], wall_height: float,
                         designs: _Designs, rng: np.random.Generator) -> None:
    """Notice boards (half the rooms that are not texture-poor; corridors every ~8 m of wall),
    0-2 more framed prints in rooms that are not texture-poor, and direction signs in
    corridors (every ~10 m of wall), where a wall has room for them."""
    by_region: dict[int, list[int]] = {}
    for i, f in enumerate(faces):
        if f.kind == "wall" and f.hi - f.lo >= 1.8:
            by_region.setdefault(f.region, []).append(i)
    rooms = [r.number for r in regions.values() if r.kind == "room"]
    for r in regions.values():
        cand = by_region.get(r.label, [])
        if not cand:
            continue
        wall_m = sum(faces[i].hi - faces[i].lo for i in cand)
        if r.kind == "room":
            rich = r.material != "painted"
            boards, prints, signs = int(rich and rng.random() < 0.5), int(rng.integers(0, 3)) if rich else 0, 0
        else:
            boards, prints, signs = max(1, int(wall_m / 8.0)), 0, max(1, int(wall_m / 10.0))
        wanted: tuple[tuple[PictureKind, int], ...] = (("notice", boards), ("print", prints), ("sign", signs))
        for kind, n in wanted:
            for _ in range(n * 4):
                if n <= 0:
                    break
                fi = int(rng.choice(cand))
                length = faces[fi].hi - faces[fi].lo
                text: tuple[str, ...] = ()
                if kind == "notice":
                    width, height, z0 = rng.uniform(0.9, 1.4), rng.uniform(0.6, 0.9), rng.uniform(0.95, 1.2)
                elif kind == "print":
                    width = rng.uniform(0.5, 1.0)
                    height, z0 = width * rng.uniform(0.6, 1.3), rng.uniform(1.0, 1.4)
                else:
                    width, height, z0 = rng.uniform(0.5, 0.8), rng.uniform(0.18, 0.28), rng.uniform(1.9, 2.2)
                    lo_r, hi_r = sorted(rng.choice(len(rooms), 2, replace=len(rooms) < 2))
                    arrow = str(rng.choice(["<-", "->"]))
                    text = (f"Rooms {rooms[lo_r].split()[0]}-{rooms[hi_r].split()[0]} {arrow}",)
                z0 = min(z0, wall_height - height - 0.1)
                if length < width + 0.4:
                    continue
                s0 = rng.uniform(0.2, length - width - 0.2)
                if _free_on_face(posters, fi, s0, width, z0, height):
                    def fits(w: float, h: float, fi: int = fi, s0: float = s0, z0: float = z0,
                             length: float = length) -> bool:
                        return s0 + w <= length - 0.1 and z0 + h <= wall_height - 0.1 and _free_on_face(
                            posters, fi, s0, w, z0, h)

                    got, design, w, h = designs.next(kind, width, height, kind != "sign", fits)
                    posters.append(Poster(fi, s0, z0, w, h, "", got, design, text))
                    n -= 1


def decorate(spec: WorldSpec, regions: dict[int, Region], faces: list[Face], doors: list[Door],
             posters: list[Poster], wall_height: float) -> list[Poster]:
    """The varied appearance's pictures: `posters` with designs of their own, plus plates,
    notice boards and signs (drawn from the building's decoration stream)."""
    rng = np.random.default_rng([spec.seed, 3])
    designs = _Designs(rng, spec.repeated_pictures)
    number_rooms(regions, rng)
    out = vary_posters(posters, regions, faces, designs, rng)
    add_plates(doors, regions, faces, out, designs, rng)
    add_boards_and_signs(regions, faces, out, wall_height, designs, rng)
    return out


def change_pictures(posters: list[Poster], rng: np.random.Generator, fraction: float,
                    kinds: tuple[PictureKind, ...] = ("photo", "poster", "print")) -> tuple[list[Poster], list[int]]:
    """A `fraction` of the pictures of `kinds` show another picture (months later): a photograph
    another image, a generated picture another design; returns the pictures and the indices of
    those that changed. Other kinds (by default plates, signs and notice boards) stay."""
    out, changed = list(posters), []
    for i, p in enumerate(out):
        if p.kind not in kinds or rng.random() >= fraction:
            continue
        if p.kind == "photo":
            others = [img for img in POSTER_IMAGES if img != p.image]
            out[i] = dataclasses.replace(p, image=str(rng.choice(others)))
        else:
            out[i] = dataclasses.replace(p, design=int(rng.integers(1, 2**31 - 1)))
        changed.append(i)
    return out, changed
