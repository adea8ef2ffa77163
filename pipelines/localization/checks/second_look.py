"""The second-look check: a query every pass refused, looked at again at full resolution.

The refused candidates that came closest (`passes.second_look_nodes`) are verified again on
denser features (`pipelines.localization.second_look.SecondLook`); its result replaces the
refusal where it accepts.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from litevloc.base.params.localization import LocalizationParams
from litevloc.pipelines.localization.passes import second_look_nodes
from litevloc.pipelines.localization.prior import Prior
from litevloc.pipelines.localization.results import LocalizationResult

Frame = tuple[NDArray[np.uint8], NDArray[np.float32] | None, NDArray[np.float64]]  # colour, depth (m), K


class SecondLookFn(Protocol):
    """GL (`local` False; the prior, if any, fusion's) or LL from `prior` (`local` True)
    verification of `nodes` only, on other features of the same query and map
    (`pipelines.localization.second_look.SecondLook`); None where it does not apply."""

    def __call__(self, t_ns: int, color: NDArray[np.uint8], depth: NDArray[np.float32] | None,
                 K: NDArray[np.float64], nodes: Sequence[int], prior: Prior | None = None,
                 local: bool = False) -> LocalizationResult | None: ...


def look_again(second_look: SecondLookFn, p: LocalizationParams, res: LocalizationResult, frame: Frame,
               prior: Prior | None, local: bool = False, also: Sequence[int] = ()) -> LocalizationResult:
    """The refused GL (or LL: `local`) result `res` after the second look at the candidates
    `second_look_nodes` picks from its attempts and then `also` (other nodes worth a look), at most
    `second_look.candidates` in all (`second_look.from_inliers`): its result where it accepts
    (`second_look` True), else `res`; either way with both looks' attempts and time ("second_look"
    ms, in "total")."""
    picked = second_look_nodes(res.attempts, p.second_look.candidates, p.second_look.from_inliers)
    nodes = list(dict.fromkeys([*picked, *also]))[:p.second_look.candidates]
    if not nodes:
        return res
    look = second_look(res.t_ns, *frame, nodes, prior, local=local)
    if look is None:
        return res
    ms = dict(res.timings_ms)
    ms["second_look"] = look.timings_ms.get("total", 0.0)
    ms["total"] = ms.get("total", 0.0) + ms["second_look"]
    attempts = res.attempts + look.attempts
    if look.accepted:
        return replace(look, attempts=attempts, timings_ms=ms, second_look=True, stop_reason=(
            f"looked at again at full resolution (nodes {nodes}): {look.stop_reason}; first look: "
            f"{res.stop_reason}"))
    return replace(res, attempts=attempts, timings_ms=ms, stop_reason=(
        f"{res.stop_reason}; looked at again at full resolution (nodes {nodes}): {look.reason}"))
