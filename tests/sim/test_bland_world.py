"""The texture-poor, repetitive test world `bland` (issue #15 item 6) against `office`."""

from __future__ import annotations

from litevloc.sim.spec import world_names
from litevloc.sim.world import load_world


def _materials(name: str) -> dict[str, int]:
    w = load_world(name)
    rooms = [r for r in w.regions.values() if r.kind == "room"]
    return {
        "rooms": len(rooms),
        "painted": sum(r.material == "painted" for r in rooms),  # plain walls: texture-poor
        "brick": sum(r.material == "brick" for r in rooms),  # one pattern repeated: repetitive
        "posters": len(w.posters),
        "boxes": len(w.boxes),
        "goals": len(w.goal_places),
    }


def test_bland_is_more_texture_poor_and_repetitive_than_office() -> None:
    assert "bland" in world_names()
    b, o = _materials("bland"), _materials("office")
    assert b["rooms"] == o["rooms"] == 6
    assert b["painted"] >= 4 > o["painted"]
    assert b["painted"] + b["brick"] == 6 > o["painted"] + o["brick"]  # no room with a distinctive wall texture
    assert b["posters"] < o["posters"] and b["boxes"] < o["boxes"]
    assert b["goals"] >= 6  # still one goal place per room (a poster in each) for navigation
