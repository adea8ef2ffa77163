"""Simulator parameters (robot, head camera, sensor rates, drift and imaging effects):
re-exported from the bottom layer `litevloc.base.params.sim`, so the configuration tree
(`config/schema.py`, section `sim`) references them without importing the simulator.
"""

from __future__ import annotations

from litevloc.base.params.sim import RealismParams as RealismParams
from litevloc.base.params.sim import SimParams as SimParams
