"""What long runs show and leave behind: progress bars on stderr and JSON summaries, shared by
the command line and the library runs it calls (map build, simulated navigation)."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

from tqdm import tqdm


def write_json(path: Path | None, data: dict[str, Any]) -> None:
    """Write `data` as indented, key-sorted JSON (numpy values and paths as plain values); no-op
    without a path."""
    if path is None:
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data, indent=2, sort_keys=True, default=_jsonable) + "\n")


def _jsonable(o: Any) -> Any:
    import numpy as np

    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def progress(total: int | None, desc: str, unit: str = "frame") -> tqdm:
    """A progress bar on stderr (quiet when stderr is not a terminal, except in CI logs)."""
    return tqdm(total=total, desc=desc, unit=unit, file=sys.stderr, dynamic_ncols=True, mininterval=0.5,
                disable=None)
