"""`--frames A:B`: the command line's selection of frame indices, as a Python slice."""

from __future__ import annotations

import re

_FRAMES_RE = re.compile(r"^\s*(-?\d*)\s*:\s*(-?\d*)\s*(?::\s*(-?\d*)\s*)?$")


def parse_frames(spec: str | None) -> slice:
    """`"A:B"` / `"A:B:S"` / `"A:"` / `":B"` / `None` -> slice (Python slice semantics)."""
    if spec is None or spec.strip() == "":
        return slice(None)
    m = _FRAMES_RE.match(spec)
    if not m:
        raise ValueError(f"--frames must look like A:B (a Python slice), got {spec!r}")
    a, b, s = (int(g) if g not in (None, "") else None for g in m.groups())
    if s == 0:
        raise ValueError(f"--frames step must not be zero: {spec!r}")
    return slice(a, b, s)
