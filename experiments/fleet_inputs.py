"""The inputs of the fleet benchmark (bench/fleet.py) and of the map-switch tests, built once and cached.

From the 7-Scenes redkitchen folder: version 1 of the map (every 5th frame of the mapping pass,
0:500:5: the fixed held-out protocol at test size), version 2 (a rebuild from other frames of the
same pass, 2:500:5: the same ground-truth map frame, no keyframe in common) and the held-out query
recording (every 10th frame of the query pass, 500:1000:10: 50 frames with 100 Hz odometry and
ground truth). Each is made by the `litevloc` console script of this interpreter's environment
(what a user types), under an exclusive file lock so parallel test workers build it once, and
skipped when the folder holds it from the same recipe.
"""

from __future__ import annotations

import fcntl
import json
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

#: `litevloc` arguments; `$D` is the 7-Scenes folder, `$OUT` the output folder
V1_ARGS = ("map", "build", "$D", "--frames", "0:500:5", "-o", "$OUT/map", "--config", "7scenes")
QUERY_ARGS = ("convert", "$D", "$OUT/query.mcap", "--frames", "500:1000:10", "--config", "7scenes")
V2_ARGS = ("map", "build", "$D", "--frames", "2:500:5", "-o", "$OUT/v2", "--config", "7scenes")


@dataclass(frozen=True)
class FleetInputs:
    """Two versions of one map in the same map frame and a recording of held-out queries."""

    v1: Path  # map folder (0:500:5)
    v2: Path  # map folder (2:500:5)
    rec: Path  # .mcap of frames 500:1000:10


def litevloc_exe() -> str:
    """The installed `litevloc` console script of this interpreter's environment."""
    return str(Path(sys.executable).with_name("litevloc"))


@contextmanager
def exclusive(lock: Path) -> Iterator[None]:
    """Hold an exclusive lock on the file `lock` (made if absent): parallel builders of one cache
    (pytest-xdist workers, a benchmark beside a test run) build it once, the others wait for it."""
    lock.parent.mkdir(parents=True, exist_ok=True)
    with lock.open("a") as f:
        fcntl.flock(f, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)


def cached_cli(args: tuple[str, ...], out: Path, done: Path, subs: dict[str, str], timeout: float = 900) -> None:
    """Run `litevloc ARGS` (each key of `subs` replaced by its value) unless `done` exists from the
    same recipe (the unsubstituted `args`, stamped beside `out`). Raises RuntimeError with the tail
    of its stderr when the command fails."""
    stamp = out.parent / f"{out.name}.recipe.json"
    recipe = list(args)
    with exclusive(out.parent / f"{out.name}.lock"):
        if stamp.is_file() and json.loads(stamp.read_text()) == recipe and done.exists():
            return
        out.parent.mkdir(parents=True, exist_ok=True)
        stamp.unlink(missing_ok=True)
        argv = [_sub(a, subs) for a in args]
        r = subprocess.run([litevloc_exe(), *argv], capture_output=True, text=True, timeout=timeout)
        if r.returncode != 0:
            raise RuntimeError(f"litevloc {' '.join(argv)} failed ({r.returncode}): {r.stderr[-3000:]}")
        stamp.write_text(json.dumps(recipe))


def _sub(arg: str, subs: dict[str, str]) -> str:
    for k, v in subs.items():
        arg = arg.replace(k, v)
    return arg


def held_out_inputs(data: Path, out: Path) -> tuple[Path, Path]:
    """(version 1 map, query recording) under `out` from the 7-Scenes folder `data`, cached."""
    subs = {"$D": str(data), "$OUT": str(out)}
    cached_cli(V1_ARGS, out / "map", out / "map" / "manifest.json", subs)
    cached_cli(QUERY_ARGS, out / "query.mcap", out / "query.mcap", subs)
    return out / "map", out / "query.mcap"


def fleet_inputs(data: Path, out: Path) -> FleetInputs:
    """Both map versions and the query recording under `out` (`map/`, `v2/`, `query.mcap`), cached."""
    v1, rec = held_out_inputs(data, out)
    cached_cli(V2_ARGS, out / "v2", out / "v2" / "manifest.json", {"$D": str(data), "$OUT": str(out)})
    return FleetInputs(v1=v1, v2=out / "v2", rec=rec)
