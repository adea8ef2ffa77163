"""Parameters of the pose-graph fusion: re-exported from the bottom layer `litevloc.base.params.fusion`."""

from __future__ import annotations

from litevloc.base.params.fusion import (
    FusionParams as FusionParams,
)
