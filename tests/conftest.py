"""Shared fixtures: paths to ../shared data (skipped with a reason where absent), and the
7-Scenes held-out inputs that several tests share (built once through the console script,
cached under out/test_cache/)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import pytest

from litevloc.experiments.fleet_inputs import (
    QUERY_ARGS,
    V1_ARGS,
    FleetInputs,
    SimFleetInputs,
    fleet_inputs,
    held_out_inputs,
    litevloc_exe,
    sim_fleet_inputs,
)

__all__ = ["HELD_OUT_MAP_ARGS", "HELD_OUT_QUERY_ARGS", "TEST_CACHE", "HeldOut", "litevloc_exe"]

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared"
SEVEN_SCENES = SHARED / "data" / "7scenes-redkitchen"
TEST_CACHE = ROOT / "out" / "test_cache"
# The fixed protocol at test size: the map from every 5th frame of the mapping pass (0-499), the
# queries from every 10th frame of the query pass (500-999); the README's 7-Scenes quick start
# runs the same two commands (tests/test_readme.py). The fleet benchmark builds the same.
HELD_OUT_MAP_ARGS = V1_ARGS
HELD_OUT_QUERY_ARGS = QUERY_ARGS


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
    map_dir, queries = held_out_inputs(seven_scenes_dir, TEST_CACHE / "held_out")
    return HeldOut(map_dir, queries, seven_scenes_dir)


@pytest.fixture(scope="session")
def seven_scenes_fleet(seven_scenes_held_out: HeldOut) -> FleetInputs:
    """The held-out map, its rebuild from other frames (2:500:5) and the query recording: the fleet
    benchmark's inputs and the map-switch tests' two versions, built once and cached."""
    return fleet_inputs(seven_scenes_held_out.data, TEST_CACHE / "held_out")


@pytest.fixture(scope="session")
def sim_fleet() -> SimFleetInputs:
    """The fleet benchmark's simulated office: a map of the first room and recordings of it after a
    change (the robots', the pushing robot's, the held-out check's), rendered once and cached."""
    return sim_fleet_inputs(TEST_CACHE / "fleet_sim")
