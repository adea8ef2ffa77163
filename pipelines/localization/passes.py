"""Later verification passes of a refused localization query, on the same features and matches.

A GL or LL query that every candidate refused is verified again, no model run again (the query's
cached matches and PnP fits are reused), each later pass only where the earlier ones refused:

* with the map's depth (`LocalizationParams.passes.map_depth`), where the map has keypoint depth
  and `verify.map_depth` is off;
* with weak candidates pooled (`passes.pooled_min_inliers` > 0): PnP's inlier floor is lowered to that
  count (`pooled`) and a weak candidate passes only where the joint refinement's keyframes explain
  the full floor together (`pooled_short`); run only when a refused candidate was weak (`weak`).

A frame an earlier pass accepts is never verified again, so what it accepts is unchanged. This
module decides the passes and their parameters; GL and LL run each pass's verification under
them (`VerifyFn`). A query every pass refused may then be looked at again at full resolution
(`checks.second_look`), on the candidates `second_look_nodes` picks.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

from litevloc.base.params.localization import LocalizationParams
from litevloc.pipelines.localization.query import StageTimer
from litevloc.pipelines.localization.refine import RefineResult
from litevloc.pipelines.localization.results import CandidateAttempt, LocalizationResult
from litevloc.pipelines.pnp import PnpResult, Refusal

VerifyFn = Callable[[LocalizationParams], LocalizationResult]  # one verification pass under these parameters


def weak(attempt: CandidateAttempt, floor: int) -> bool:
    """Whether a refused candidate had `floor` inliers (or matches, where too few matches stopped it
    before PnP): one that pooling over keyframes could still let through."""
    return ((attempt.refusal is Refusal.INLIERS and attempt.inliers >= floor)
            or (attempt.refusal is Refusal.MATCHES and attempt.matches >= floor))


def pooled(p: LocalizationParams) -> LocalizationParams:
    """`p` with PnP's inlier floor lowered to `passes.pooled_min_inliers` (a weak candidate then
    reaches the joint refinement, see `pooled_short`); `p` itself when that is off."""
    k = p.passes.pooled_min_inliers
    return replace(p, pnp=replace(p.pnp, min_inliers=k)) if 0 < k < p.pnp.min_inliers else p


def with_pooled(p: LocalizationParams, k: int) -> LocalizationParams:
    """`p` with the pooled pass's inlier floor `passes.pooled_min_inliers` set to `k` (0: no pooling)."""
    return replace(p, passes=replace(p.passes, pooled_min_inliers=k))


def pooled_short(res: PnpResult, joint: RefineResult | None, floor: int, min_keyframes: int) -> str:
    """'' when the candidate's PnP has `floor` inliers, or when it has fewer and the joint
    refinement's keyframes (at least `min_keyframes`) explain `floor` inliers together;
    else the refusal reason."""
    if res.n_inliers >= floor:
        return ""
    if (joint is not None and joint.accepted and joint.consistent_keyframes >= min_keyframes
            and joint.n_inliers >= floor):
        return ""
    how = "no joint refinement" if joint is None else (
        f"{joint.n_inliers} over {joint.consistent_keyframes} keyframe(s): {joint.reason}")
    return f"too few inliers ({res.n_inliers} < {floor}; pooled {how})"


def passes(p: LocalizationParams, map_has_depth: bool, allowed: bool,
           pooling: bool = True) -> list[tuple[LocalizationParams, str]]:
    """The passes in order, each (its parameters, how the stop reason names it; '' for the first).
    `allowed`: whether the map-depth pass may run (LL only from a fresh prior, whose gate keeps a
    repeated place out); it turns GL's distinctiveness test on (map depth lets a repeated place
    verify too). `pooling`: whether the pooled pass may run (not in the second look)."""
    first = with_pooled(p, 0)
    out: list[tuple[LocalizationParams, str]] = [(first, "")]
    if allowed and p.passes.map_depth and not p.verify.map_depth and map_has_depth:
        ratio = p.passes.map_depth_distinct_ratio or p.distinctiveness.ratio
        out.append((replace(first, verify=replace(first.verify, map_depth=True),
                            distinctiveness=replace(first.distinctiveness, ratio=ratio)),
                    "verified again with the map's depth"))
    if pooling and p.passes.pooled_min_inliers > 0:
        out.append((with_pooled(out[-1][0], p.passes.pooled_min_inliers), "verified again with weak candidates pooled"))
    return out


def with_second_passes(verify: VerifyFn, p: LocalizationParams, timer: StageTimer, map_has_depth: bool,
                       allowed: bool = True, pooling: bool = True) -> LocalizationResult:
    """`verify(params)` under each of `passes(p, ...)` until one accepts (a pooled pass only where
    a refused candidate was `weak`). The refusals' attempts are kept in front and their reasons
    named in the stop reason; `timer`'s total is the whole query's, all passes."""
    attempts: tuple[CandidateAttempt, ...] = ()
    refusals: list[str] = []  # the reasons of the passes refused before the last one run
    res: LocalizationResult | None = None
    last_how = ""
    for params, how in passes(p, map_has_depth, allowed, pooling):
        if res is not None:
            if res.accepted or (params.passes.pooled_min_inliers
                                and not any(weak(a, params.passes.pooled_min_inliers) for a in attempts)):
                break  # accepted, or no candidate that a weaker floor could let through
            refusals.append(res.reason)
            timer.ms.pop("total", None)
        res = verify(params)
        attempts += res.attempts
        last_how = how
    assert res is not None
    if not refusals:
        return res
    return replace(res, attempts=attempts, stop_reason=f"{res.stop_reason}; {last_how} ({'; '.join(refusals)})")


def second_look_nodes(attempts: tuple[CandidateAttempt, ...], n: int, min_inliers: int) -> list[int]:
    """The refused candidates a full-resolution second look verifies again: at most `n` nodes whose
    PnP found at least `min_inliers` inliers in any pass (their most; 0: every candidate), most
    inliers first, then most matches; [] when none did (a frame where nothing came close costs no
    second look)."""
    best: dict[int, tuple[int, int]] = {}
    for a in attempts:
        best[a.node] = max(best.get(a.node, (0, 0)), (a.inliers, a.matches))
    strong = [(node, ab) for node, ab in best.items() if ab[0] >= min_inliers]
    strong.sort(key=lambda v: (-v[1][0], -v[1][1], v[0]))
    return [node for node, _ in strong[:n]]
