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
* Each query runs its geometry on one BLAS thread (`OneBlasThread`).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from typing import TypeVar

import numpy as np
from numpy.typing import NDArray
from threadpoolctl import ThreadpoolController

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

R = TypeVar("R")


class OneBlasThread:
    """Runs a call with BLAS (OpenBLAS, MKL: numpy's and scipy's) limited to one thread, the
    previous limit restored after it. A query's matrix products are small (512 x 512 descriptor
    similarities, the joint solve's SVD of a few thousand x 6 Jacobian), where waking and
    spin-waiting BLAS threads costs more than the work: on a shared 2-core machine a 512 x 128 x 512
    product took 50 ms on OpenBLAS's two threads and 1.6 ms on one, an SVD of 3000 x 6 46 ms and 1.7 ms.
    The model runtimes keep their own thread pools (onnxruntime does not use BLAS). The libraries
    are looked up once, here (the pipelines' imports have loaded scipy's OpenBLAS by then)."""

    def __init__(self) -> None:
        self._controller = ThreadpoolController()

    def __call__(self, fn: Callable[[], R]) -> R:
        with self._controller.limit(limits=1, user_api="blas"):
            return fn()


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
        self.one_blas_thread = OneBlasThread()

    def process(self, t_ns: int, color: NDArray[np.uint8], depth: NDArray[np.float32] | None,
                K: NDArray[np.float64], prior: Prior | None = None,
                region: SearchRegion | None = None) -> LocalizationResult:
        """One frame through the state machine (`Tracker.process`)."""
        return self.one_blas_thread(lambda: self.tracker.process(t_ns, color, depth, K, prior, region))

    def localize_global(self, t_ns: int, color: NDArray[np.uint8], depth: NDArray[np.float32] | None,
                        K: NDArray[np.float64], prior: Prior | None = None, region: SearchRegion | None = None,
                        only: Sequence[int] | None = None) -> LocalizationResult:
        """One GL query outside the state machine (`GlobalSearch.localize`, not recovering)."""
        return self.one_blas_thread(lambda: self.global_search.localize(t_ns, color, depth, K, self.params, prior,
                                                                        region=region, only=only))

    def localize_local(self, t_ns: int, color: NDArray[np.uint8], depth: NDArray[np.float32] | None,
                       K: NDArray[np.float64], prior: Prior, only: Sequence[int] | None = None) -> LocalizationResult:
        """One LL query from `prior` outside the state machine (`LocalSearch.localize`)."""
        return self.one_blas_thread(lambda: self.local_search.localize(t_ns, color, depth, K, self.params, prior,
                                                                       only))
