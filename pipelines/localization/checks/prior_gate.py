"""The prior-gate check (LL): a candidate's pose must lie within the gate of the prior it came from."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from litevloc.base.geometry import relative_pose_error
from litevloc.pipelines.localization import prior as pg
from litevloc.pipelines.localization.query import Query
from litevloc.pipelines.localization.results import CandidateAttempt
from litevloc.pipelines.localization.verifier import Candidate


@dataclass(frozen=True, eq=False)
class PriorGateCheck:
    """Within `radius_m` of the prior `T_prior` (4x4), narrowed toward the pose by fusion's 3x3
    position covariance `cov` (`prior.gate_toward`), and within `prior_gate.deg` of its rotation."""

    T_prior: NDArray[np.float64]
    radius_m: float
    cov: NDArray[np.float64] | None

    def __call__(self, c: Candidate, q: Query) -> CandidateAttempt | None:
        assert c.T_map_camera is not None and c.attempt is not None
        dt, dr = relative_pose_error(c.T_map_camera, self.T_prior)
        radius = pg.gate_toward(q.params, c.T_map_camera, self.T_prior, self.radius_m, self.cov)
        if dt > radius or dr > q.params.prior_gate.deg:
            return CandidateAttempt(c.node, c.similarity, c.attempt.matches, c.attempt.inliers,
                                    f"inconsistent with the prior ({dt:.2f} m > {radius:.2f} m or {dr:.0f} deg)")
        return None
