"""Shared fixtures: paths to ../shared data (skipped with a reason where absent)."""

from __future__ import annotations

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared"
SEVEN_SCENES = SHARED / "data" / "7scenes-redkitchen"


@pytest.fixture(scope="session")
def seven_scenes_dir() -> Path:
    """The 7-Scenes redkitchen folder (1000 frames); skips the test where it is absent."""
    if not (SEVEN_SCENES / "frame-000000.color.jpg").is_file():
        pytest.skip(f"7-Scenes data not found at {SEVEN_SCENES} (needs ../shared beside the project)")
    return SEVEN_SCENES
