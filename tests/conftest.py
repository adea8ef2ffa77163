"""Shared fixtures: paths to ../shared data (skipped with a reason where absent), and the
7-Scenes held-out inputs that several tests share (built once through the console script,
cached under out/test_cache/)."""

from __future__ import annotations

import fcntl
import json
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared"
SEVEN_SCENES = SHARED / "data" / "7scenes-redkitchen"
TEST_CACHE = ROOT / "out" / "test_cache"
# The fixed protocol at test size: the map from every 5th frame of the mapping pass (0-499), the
# queries from every 10th frame of the query pass (500-999); the README's 7-Scenes quick start
# runs the same two commands (tests/test_readme.py).
HELD_OUT_MAP_ARGS = ("map", "build", "$D", "--frames", "0:500:5", "-o", "$OUT/map", "--config", "7scenes")
HELD_OUT_QUERY_ARGS = ("convert", "$D", "$OUT/query.mcap", "--frames", "500:1000:10", "--config", "7scenes")


def litevloc_exe() -> str:
    """The installed `litevloc` console script of this interpreter's environment."""
    return str(Path(sys.executable).with_name("litevloc"))


@contextmanager
def exclusive(lock: Path) -> Iterator[None]:
    """Hold an exclusive lock on the file `lock` (made if absent): the suite's parallel workers
    (pytest-xdist) build a shared cache once, the others wait for it."""
    lock.parent.mkdir(parents=True, exist_ok=True)
    with lock.open("a") as f:
        fcntl.flock(f, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)


def cached_cli(args: tuple[str, ...], out: Path, done: Path, subs: dict[str, str], timeout: float = 900) -> None:
    """Run `litevloc ARGS` (with `subs` substituted) unless `done` exists from the same recipe."""
    stamp = out.parent / f"{out.name}.recipe.json"
    recipe = list(args)
    with exclusive(out.parent / f"{out.name}.lock"):
        if stamp.is_file() and json.loads(stamp.read_text()) == recipe and done.exists():
            return
        out.parent.mkdir(parents=True, exist_ok=True)
        stamp.unlink(missing_ok=True)
        argv = [a for arg in args for a in [_sub(arg, subs)]]
        r = subprocess.run([litevloc_exe(), *argv], capture_output=True, text=True, timeout=timeout)
        assert r.returncode == 0, r.stderr[-3000:]
        stamp.write_text(json.dumps(recipe))


def _sub(arg: str, subs: dict[str, str]) -> str:
    for k, v in subs.items():
        arg = arg.replace(k, v)
    return arg


@dataclass(frozen=True)
class HeldOut:
    """A 7-Scenes map of the mapping pass and a recording of held-out query frames."""

    map_dir: Path
    queries: Path  # .mcap of frames 500:1000:10 (50 frames, 100 Hz drift odometry, ground truth)
    data: Path  # the 7-Scenes folder


@pytest.fixture(scope="session")
def seven_scenes_dir() -> Path:
    """The 7-Scenes redkitchen folder (1000 frames); skips the test where it is absent."""
    if not (SEVEN_SCENES / "frame-000000.color.jpg").is_file():
        pytest.skip(f"7-Scenes data not found at {SEVEN_SCENES} (needs ../shared beside the project)")
    return SEVEN_SCENES


@pytest.fixture(scope="session")
def seven_scenes_held_out(seven_scenes_dir: Path) -> HeldOut:
    """(map of frames 0:500:5, recording of frames 500:1000:10), built once and cached."""
    out = TEST_CACHE / "held_out"
    subs = {"$D": str(seven_scenes_dir), "$OUT": str(out)}
    cached_cli(HELD_OUT_MAP_ARGS, out / "map", out / "map" / "manifest.json", subs)
    cached_cli(HELD_OUT_QUERY_ARGS, out / "query.mcap", out / "query.mcap", subs)
    return HeldOut(out / "map", out / "query.mcap", seven_scenes_dir)
