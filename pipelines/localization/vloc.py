"""Coarse-to-fine visual localization against a map-lite `TopoMap`: the localizer assembled.

* Global localization (GL, `global_search`): VPR top-k retrieval over the map's descriptors,
  each candidate verified geometrically; the result says "not localized" rather than guess.
* Local localization (LL, `local_search`): from a prior `T_map_camera`, the map nodes around it
  verified in similarity order until one is accepted.
* Both verify a candidate with one `verifier.CandidateVerifier`: PnP + RANSAC into the keyframe,
  the support check (GL), the joint refinement over covisible keyframes (`refine.py`), then GL's
  distinctiveness check (`checks.distinctiveness`); later passes (`passes.py`) verify a refused
  query again on the same features and matches, and the second look (`checks.second_look`)
  at full resolution, its pose checked against the live depth (`checks.see_through`).
* `Tracker.process` runs the state machine INIT -> GLOBAL -> TRACKING -> LOST -> GLOBAL
  (`tracking.TrackingState`) and holds a pose its prior cannot confirm until it repeats.
"""

from __future__ import annotations

import time
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from litevloc.base.loader import ConfigError
from litevloc.base.params.localization import LocalizationParams
from litevloc.pipelines.localization.checks.second_look import SecondLookFn
from litevloc.pipelines.localization.global_search import GlobalSearch
from litevloc.pipelines.localization.local_search import LocalSearch
from litevloc.pipelines.localization.prior import Prior
from litevloc.pipelines.localization.query import Clock, MatchFn
from litevloc.pipelines.localization.results import LocalizationResult
from litevloc.pipelines.localization.search_region import SearchRegion
from litevloc.pipelines.localization.tracker import Tracker
from litevloc.pipelines.localization.verifier import CandidateVerifier, DescribeFn, ExtractFn
from litevloc.pipelines.topomap.types import TopoMap


class VisualLocalizer:
    """GL + LL against one map with injected model callables (no I/O, no threads), and the
    tracking state machine over them (`tracker`); `second_look`: the full-resolution look
    (needed where `second_look.candidates` > 0)."""

    def __init__(
        self, topomap: TopoMap, params: LocalizationParams, extract: ExtractFn, describe: DescribeFn, match: MatchFn,
        clock: Clock = time.perf_counter, second_look: SecondLookFn | None = None,
    ) -> None:
        if params.second_look.candidates > 0 and second_look is None:
            raise ConfigError("localization.second_look.candidates > 0 needs the second look's models; this command "
                              "does not load them: set it to 0 here")
        look = second_look if params.second_look.candidates > 0 else None
        self.params = params
        self.verifier = CandidateVerifier(topomap, extract, describe, match, clock)
        self.local_search = LocalSearch(self.verifier, look)
        self.global_search = GlobalSearch(self.local_search, look)
        self.tracker = Tracker(params, self.global_search, self.local_search)

    def process(self, t_ns: int, color: NDArray[np.uint8], depth: NDArray[np.float32] | None,
                K: NDArray[np.float64], prior: Prior | None = None,
                region: SearchRegion | None = None) -> LocalizationResult:
        """One frame through the state machine (`Tracker.process`)."""
        return self.tracker.process(t_ns, color, depth, K, prior, region)

    def localize_global(self, t_ns: int, color: NDArray[np.uint8], depth: NDArray[np.float32] | None,
                        K: NDArray[np.float64], prior: Prior | None = None, region: SearchRegion | None = None,
                        only: Sequence[int] | None = None) -> LocalizationResult:
        """One GL query outside the state machine (`GlobalSearch.localize`, not recovering)."""
        return self.global_search.localize(t_ns, color, depth, K, self.params, prior, region=region, only=only)

    def localize_local(self, t_ns: int, color: NDArray[np.uint8], depth: NDArray[np.float32] | None,
                       K: NDArray[np.float64], prior: Prior, only: Sequence[int] | None = None) -> LocalizationResult:
        """One LL query from `prior` outside the state machine (`LocalSearch.localize`)."""
        return self.local_search.localize(t_ns, color, depth, K, self.params, prior, only)
