"""The inputs of the fleet benchmark (bench/fleet.py) and of the map-switch tests, built once and cached.

The benchmark's (`sim_fleet_inputs`), from the simulated office (`litevloc sim record`, no data
needed): version 1 of the map from the first 40 s of the mapping pass (the first room: its centre
turn and edge sweeps), and three recordings of the same building after a change (the `change:`
block's `furniture=0.3`: a cabinet of that room slid along its wall, others elsewhere): the one
each robot replays (mapping-pass route, seed 5; every 5th camera frame kept: 3 Hz, the runtime's
VLoc rate, odometry at its full 200 Hz), the pushing robot's mapping pass of the changed
room (seed 3, 10 s: what `litevloc map push` sends) and the map service's held-out check (seed 7,
40 s). Seeds differ in lighting, drift and noise; the route of the mapping pass is the same.

The map-switch tests' (`fleet_inputs`), from the 7-Scenes redkitchen folder: version 1 of the map
(every 5th frame of the mapping pass, 0:500:5: the fixed held-out protocol at test size), version 2
(a rebuild from other frames of the same pass, 2:500:5: the same ground-truth map frame, no keyframe
in common) and the held-out query recording (every 10th frame of the query pass, 500:1000:10: 50
frames with 100 Hz odometry and ground truth).

Each is made by the `litevloc` console script of this interpreter's environment (what a user
types), under an exclusive file lock so parallel test workers build it once, and skipped when the
folder holds it from the same recipe.
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


#: the simulated fleet's recipes (`$OUT` the output folder); the change is the same in all three
SIM_CHANGE = ("--change", "furniture=0.3")
SIM_V1_REC_ARGS = ("sim", "record", "office", "--pass", "map", "--seed", "0", "--duration", "40", "-o", "$OUT/v1.mcap")
SIM_V1_ARGS = ("map", "build", "$OUT/v1.mcap", "-o", "$OUT/map", "--config", "default")
SIM_REC_ARGS = ("sim", "record", "office", "--pass", "map", "--seed", "5", "--duration", "40", *SIM_CHANGE,
                "-o", "$OUT/robots15.mcap")
SIM_REC_3HZ_ARGS = ("convert", "$OUT/robots15.mcap", "$OUT/robots.mcap", "--frames", "::5", "--config", "default")
SIM_PUSH_ARGS = ("sim", "record", "office", "--pass", "map", "--seed", "3", "--duration", "10", *SIM_CHANGE,
                 "-o", "$OUT/push.mcap")
SIM_HELD_OUT_ARGS = ("sim", "record", "office", "--pass", "map", "--seed", "7", "--duration", "40", *SIM_CHANGE,
                     "-o", "$OUT/held_out.mcap")


@dataclass(frozen=True)
class SimFleetInputs:
    """The simulated fleet: a map, and recordings of the building after a change (all posed by
    the simulator's ground truth, in the map's frame)."""

    v1: Path  # map folder: the office's mapping pass, first 40 s
    rec: Path  # .mcap each robot replays (changed building; every 5th camera frame: 3 Hz, odometry 200 Hz)
    push: Path  # .mcap the pushing robot sends (changed room, 10 s)
    held_out: Path  # .mcap of the map service's held-out check (changed building)


def sim_fleet_inputs(out: Path) -> SimFleetInputs:
    """The simulated fleet's map and recordings under `out`, cached (rendering them: ~2 min of CPU)."""
    subs = {"$OUT": str(out)}
    cached_cli(SIM_V1_REC_ARGS, out / "v1.mcap", out / "v1.mcap", subs)
    cached_cli(SIM_V1_ARGS, out / "map", out / "map" / "manifest.json", subs)
    for args, name in ((SIM_REC_ARGS, "robots15"), (SIM_REC_3HZ_ARGS, "robots"), (SIM_PUSH_ARGS, "push"),
                       (SIM_HELD_OUT_ARGS, "held_out")):
        cached_cli(args, out / f"{name}.mcap", out / f"{name}.mcap", subs)
    return SimFleetInputs(v1=out / "map", rec=out / "robots.mcap", push=out / "push.mcap",
                          held_out=out / "held_out.mcap")


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
