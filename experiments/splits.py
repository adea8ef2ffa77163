"""Cross-split benchmark of localization on the 7-Scenes sequence (`bench/splits.py`).

The rule, fixed before any parameter was chosen on it (docs/localization.md):

* The 1000 frames form four blocks of 250 contiguous frames (B0 = 0-249 ... B3 = 750-999).
  A map built from one block is queried with the block before it and the block after it:
  six splits `B0>B1`, `B1>B0`, `B1>B2`, `B2>B1`, `B2>B3`, `B3>B2`.
* The published split (map 0-499, queries 500-999) and its reverse (map 500-999, queries 0-499).
* Choosing splits (where a parameter may be chosen): `B0>B1` and `B1>B0`, both inside the
  mapping pass (frames 0-499), where the earlier defaults were chosen too. Every other split,
  the published one included, is a report split. All eight are reported; figures of the
  choosing splits are labelled as such.

Each query frame runs through `VisualLocalizer.process` in order (the state machine of
`litevloc localize`: GL at start-up and when lost, LL from the last accepted pose), with the
`7scenes` preset (colour-camera ground truth). Per frame it records whether the map covers the
frame (a keyframe within 0.5 m and 30 deg of the ground truth; and within 1 m and 45 deg), the
outcome and its error, the rank of the first covering keyframe in the place-recognition order,
and for a refused GL query why its covering candidates failed (`split_report.failure_of`).
"""

from __future__ import annotations

import shutil
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from litevloc.base.geometry import relative_pose_error
from litevloc.config import load_config
from litevloc.experiments.model_replay import ReplayedModels
from litevloc.experiments.split_report import failure_of, summarize
from litevloc.pipelines.localization.results import LocalizationResult
from litevloc.pipelines.localization.vloc import VisualLocalizer
from litevloc.pipelines.topomap.io import load_map
from litevloc.pipelines.topomap.types import TopoMap
from litevloc.runtime.sources import open_source
from litevloc.runtime.tools.posed import posed_frames
from litevloc.runtime.vloc_models import check_map_models, load_bundle, second_look_for

BLOCK = 250
COVER = ((0.5, 30.0), (1.0, 45.0))  # (metres, degrees): "covered", and the looser "near"


@dataclass(frozen=True)
class Split:
    """A map built from frames [map_frames) queried with frames [query_frames) (Python ranges)."""

    name: str
    map_frames: tuple[int, int]
    query_frames: tuple[int, int]
    role: Literal["choose", "report"]


def _block_splits() -> list[Split]:
    out = []
    for m in range(4):
        for q in (m - 1, m + 1):
            if 0 <= q < 4:
                role: Literal["choose", "report"] = "choose" if {m, q} == {0, 1} else "report"
                out.append(Split(f"B{m}>B{q}", (m * BLOCK, (m + 1) * BLOCK), (q * BLOCK, (q + 1) * BLOCK), role))
    return out


SPLITS: tuple[Split, ...] = (
    *_block_splits(),
    Split("published", (0, 500), (500, 1000), "report"),
    Split("reverse", (500, 1000), (0, 500), "report"),
)


def splits_named(names: Sequence[str]) -> list[Split]:
    """The splits with these names (all when empty); ValueError naming the known ones."""
    known = {s.name: s for s in SPLITS}
    bad = [n for n in names if n not in known]
    if bad:
        raise ValueError(f"unknown split(s) {bad}; known: {', '.join(known)}")
    return [known[n] for n in names] if names else list(SPLITS)


def ensure_map(data: Path, split: Split, maps_dir: Path, config: str, build: Callable[[list[str]], int]) -> Path:
    """The split's map folder under `maps_dir`, built with `build(argv)` (the `litevloc` CLI's
    main) when absent; written under a temporary name and renamed when complete."""
    a, b = split.map_frames
    path = maps_dir / f"map-{a}-{b - 1}"
    if (path / "manifest.json").is_file():
        return path
    tmp = path.with_name(path.name + ".partial")
    shutil.rmtree(tmp, ignore_errors=True)
    argv = ["map", "build", str(data), "--frames", f"{a}:{b}", "-o", str(tmp), "--force", "--config", config]
    if build(argv) != 0:
        raise RuntimeError(f"map build failed: litevloc {' '.join(argv)}")
    tmp.replace(path)
    return path


def coverage(topomap: TopoMap, T_gt: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(N,) distance (m) and (N,) viewing-direction difference (deg) of every keyframe from the
    ground-truth pose `T_gt` (4x4 T_map_camera)."""
    d = np.linalg.norm(topomap.T_map_camera[:, :3, 3] - T_gt[:3, 3], axis=1)
    a = np.array([relative_pose_error(T, T_gt)[1] for T in topomap.T_map_camera])
    return d, a


def frame_record(index: int, res: LocalizationResult, T_gt: NDArray[np.float64], topomap: TopoMap,
                 vpr: NDArray[np.float32], shortlist: int, latency_ms: float) -> dict[str, Any]:
    """What one query frame tells the benchmark (plain data for the JSON); `shortlist`: how
    many nodes, by place-descriptor similarity, GL ranks."""
    d, a = coverage(topomap, T_gt)
    covering = (d <= COVER[0][0]) & (a <= COVER[0][1])
    order = np.argsort(-(topomap.vpr @ vpr), kind="stable")
    ranks = np.flatnonzero(covering[order])
    rec: dict[str, Any] = {
        "frame": index, "mode": res.mode, "accepted": bool(res.accepted), "reason": res.reason,
        "covered": bool(covering.any()), "near": bool(((d <= COVER[1][0]) & (a <= COVER[1][1])).any()),
        "nearest_m": float(d.min()), "first_covering_rank": int(ranks[0]) + 1 if len(ranks) else -1,
        "latency_ms": latency_ms, "candidates_tried": len(res.attempts),
    }
    if res.accepted and res.T_map_camera is not None:
        rec["error_m"], rec["error_deg"] = relative_pose_error(res.T_map_camera, T_gt)
    elif rec["covered"]:
        rec["failure"] = failure_of(res, set(np.flatnonzero(covering).tolist()), order[:shortlist].tolist())
    return rec


def run_split(split: Split, map_dir: Path, data: Path, config: str, overrides: Sequence[str], cache_dir: Path,
              step: int = 1, on_frame: Callable[[int, int], None] | None = None) -> dict[str, Any]:
    """Localize the split's query frames (every `step`-th) in order; per-frame records + summary.
    `on_frame(done, total)` reports progress."""
    cfg = load_config(config, list(overrides))
    bundle = load_bundle(cfg.models)
    topomap = check_map_models(load_map(map_dir), bundle)
    models = ReplayedModels(cache_dir, bundle, topomap, map_dir)
    # the second look's models are called live (its features are not recorded)
    loc = VisualLocalizer(topomap, cfg.localization, models.extract, models.describe, models.match,
                          clock=models.clock,
                          second_look=second_look_for(topomap, cfg.models, cfg.localization, bundle, models.clock))
    lp = cfg.localization
    shortlist = max(lp.global_search.top_k, lp.global_search.rerank_depth if lp.global_search.rerank else 0)
    a, b = split.query_frames
    src = open_source(data, slice(a, b, step), strict=True, rgbd_calibration=cfg.rgbd_calibration)
    records: list[dict[str, Any]] = []
    t0 = time.perf_counter()
    total = len(range(a, b, step))
    for frame, T_gt in posed_frames(src):
        if T_gt is None:
            raise RuntimeError(f"frame {frame.index} of {data} has no ground-truth pose")
        models.start(frame.index)
        res = loc.process(frame.t_ns, frame.color, frame.depth, frame.K)
        records.append(frame_record(frame.index, res, T_gt, topomap, models.descriptor(), shortlist,
                                    res.timings_ms.get("total", float("nan"))))
        if on_frame is not None:
            on_frame(len(records), total)
    models.flush()
    return {
        "split": split.name, "role": split.role, "map_frames": list(split.map_frames),
        "query_frames": [a, b, step], "map": str(map_dir), "keyframes": topomap.n_nodes,
        "wall_s": time.perf_counter() - t0, "model_calls": dict(models.calls),
        "summary": summarize(records), "frames": records,
    }
