"""The loop probe: GL from no prior in the simulated `loop` world's repeating corridor.

A safety check beside the 7-Scenes splits (`bench/splits.py --loop-probe`): the ring corridor
repeats its wall texture, so a pose verified at the wrong period of it is a wrong fix. Every
`every`-th frame of the `loop-lane` query pass (seed 1) is localized by GL alone, a fresh
`VisualLocalizer` per frame (no prior, no state), against the loop map of `bench/loop.py`
(`out/bench/loop/map`). The query frames are recorded once under `frames_dir` (npz: colour,
depth, K, stamp, ground truth; rendered by `record_loop_frames` where missing) so that the map,
the frames and the model calls replayed from `cache_dir` (`experiments.model_replay`) all come
from the same simulator.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from litevloc.base.geometry import relative_pose_error
from litevloc.config import load_config
from litevloc.experiments.model_replay import ReplayedModels
from litevloc.pipelines.localization.vloc import VisualLocalizer
from litevloc.pipelines.topomap.io import load_map
from litevloc.runtime.vloc_models import check_map_models, load_bundle, second_look_for
from litevloc.sim.source import open_sim_source

LOOP_QUERY = "sim:loop?pass=loop-lane&seed=1"
WRONG_M = 0.5  # an accepted pose farther than this from the ground truth is a wrong fix (m)


def _frame_file(frames_dir: Path, index: int) -> Path:
    return frames_dir / f"frame_{index:05d}.npz"


def record_loop_frames(frames_dir: Path, indices: Sequence[int]) -> None:
    """Render the loop query frames `indices` missing under `frames_dir` with this simulator."""
    missing = [i for i in indices if not _frame_file(frames_dir, i).is_file()]
    if not missing:
        return
    frames_dir.mkdir(parents=True, exist_ok=True)
    src = open_sim_source(LOOP_QUERY)
    T_world_camera = src.camera_poses()
    for i in missing:
        f = src.frame(i)
        assert f.depth is not None  # the simulator always renders depth
        np.savez_compressed(_frame_file(frames_dir, i), color=f.color, depth=f.depth, K=f.K,
                            t_ns=np.int64(f.t_ns), T_world_camera=T_world_camera[i])


def run_loop_probe(map_dir: Path, frames_dir: Path, overrides: Sequence[str], cache_dir: Path,
                   every: int = 200, last: int = 6000,
                   on_frame: Callable[[int, int], None] | None = None) -> dict[str, Any]:
    """GL alone on frames 0, `every`, ... <= `last` of the loop query pass; per-frame records
    (accepted, error in m / deg, reason, keyframes) and a summary (accepted, wrong > 0.5 m,
    GL latency median in ms)."""
    cfg = load_config("default", list(overrides))
    bundle = load_bundle(cfg.models)
    topomap = check_map_models(load_map(map_dir), bundle)
    models = ReplayedModels(cache_dir, bundle, topomap, map_dir)
    look = second_look_for(topomap, cfg.models, cfg.localization, bundle, models.clock)  # one cache for all frames
    indices = list(range(0, last + 1, every))
    record_loop_frames(frames_dir, indices)
    records: list[dict[str, Any]] = []
    t0 = time.perf_counter()
    for i in indices:
        with np.load(_frame_file(frames_dir, i), allow_pickle=False) as z:
            color, depth, K, t_ns, T_gt = z["color"], z["depth"], z["K"], int(z["t_ns"]), z["T_world_camera"]
        models.start(i)
        loc = VisualLocalizer(topomap, cfg.localization, models.extract, models.describe, models.match,
                              clock=models.clock, second_look=look)
        res = loc.localize_global(t_ns, color, depth, K)
        rec: dict[str, Any] = {"frame": i, "accepted": bool(res.accepted), "reason": res.reason,
                               "keyframes": list(res.keyframes), "n_inliers": res.n_inliers,
                               "candidates_tried": len(res.attempts),
                               "latency_ms": res.timings_ms.get("total", float("nan"))}
        if res.accepted and res.T_map_camera is not None:
            rec["error_m"], rec["error_deg"] = relative_pose_error(res.T_map_camera, T_gt)
        records.append(rec)
        if on_frame is not None:
            on_frame(len(records), len(indices))
    models.flush()
    acc = [r for r in records if r["accepted"]]
    return {"query": LOOP_QUERY, "every": every, "map": str(map_dir), "wall_s": time.perf_counter() - t0,
            "model_calls": dict(models.calls), "frames": records,
            "summary": {"queries": len(records), "accepted": len(acc),
                        "wrong": sum(r["error_m"] > WRONG_M for r in acc),
                        "max_error_m": max((r["error_m"] for r in acc), default=float("nan")),
                        "gl_ms_median": float(np.median([r["latency_ms"] for r in records]))}}
