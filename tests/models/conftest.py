"""Fixtures for model tests: the model cache (exported on first use; a no-op when current)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from litevloc.base.params.models import ModelsConfig
from litevloc.models.catalog import DEFAULT_EXPORTS
from litevloc.models.registry import default_cache_dir


@pytest.fixture(scope="session")
def model_cache() -> Path:
    """The default model cache with the default models (what `make test` exports first)."""
    pytest.importorskip("torch")
    from litevloc.models.export.exporter import export_models

    cache = default_cache_dir()
    export_models(DEFAULT_EXPORTS, cache)
    return cache


@pytest.fixture(scope="session")
def models_cfg(model_cache: Path) -> ModelsConfig:
    return ModelsConfig(cache_dir=str(model_cache))


@pytest.fixture(scope="session")
def frame_rgb(seven_scenes_dir: Path):  # type: ignore[no-untyped-def]
    """frame_rgb(i) -> HxWx3 uint8 RGB of 7-Scenes frame i."""

    def read(i: int) -> np.ndarray:
        bgr = cv2.imread(str(seven_scenes_dir / f"frame-{i:06d}.color.jpg"), cv2.IMREAD_COLOR)
        assert bgr is not None
        return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)

    return read


@pytest.fixture(scope="session")
def frame_pose(seven_scenes_dir: Path):  # type: ignore[no-untyped-def]
    """frame_pose(i) -> T_world_cam (4x4 float64) of 7-Scenes frame i."""

    def read(i: int) -> np.ndarray:
        return np.loadtxt(seven_scenes_dir / f"frame-{i:06d}.pose.txt")

    return read
