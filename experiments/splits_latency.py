"""GL latency of two configurations on the same frames, interleaved (`bench/splits.py --gl-latency`).

On a shared machine an absolute latency says more about the load than about the code: this
measures GL from no prior (a fresh `VisualLocalizer` per query, as at start-up) with the
defaults and with `overrides` on every `step`-th query frame of one split, the two runs of a
frame back to back, the models called live (no replay, one model bundle shared), and reports
both medians and their ratio.
"""

from __future__ import annotations

import os
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from litevloc.config import load_config
from litevloc.experiments.splits import Split
from litevloc.pipelines.localization.vloc import VisualLocalizer
from litevloc.pipelines.topomap.io import load_map
from litevloc.runtime.sources import open_source
from litevloc.runtime.tools.posed import posed_frames
from litevloc.runtime.vloc_models import check_map_models, load_bundle, second_look_for


def gl_latency(split: Split, map_dir: Path, data: Path, config: str, overrides: Sequence[str],
               step: int) -> dict[str, Any]:
    """Per-frame GL wall times (ms) of the defaults ("base") and of `overrides` ("new"),
    their medians, the median of the per-frame ratios, and the load average around the run."""
    cfgs = {"base": load_config(config, []), "new": load_config(config, list(overrides))}
    bundle = load_bundle(cfgs["base"].models)
    topomap = check_map_models(load_map(map_dir), bundle)
    a, b = split.query_frames
    src = open_source(data, slice(a, b, step), strict=True, rgbd_calibration=cfgs["base"].rgbd_calibration)
    ms: dict[str, list[float]] = {"base": [], "new": []}
    looks = {k: second_look_for(topomap, c.models, c.localization, bundle) for k, c in cfgs.items()}
    load = [os.getloadavg()[0]]
    for frame, _ in posed_frames(src):
        for name, cfg in cfgs.items():
            loc = VisualLocalizer(topomap, cfg.localization, bundle.extract, bundle.describe, bundle.match,
                                  second_look=looks[name])
            t0 = time.perf_counter()
            loc.localize_global(frame.t_ns, frame.color, frame.depth, frame.K)
            ms[name].append((time.perf_counter() - t0) * 1e3)
    load.append(os.getloadavg()[0])
    ratio = np.asarray(ms["new"]) / np.asarray(ms["base"])
    return {"split": split.name, "step": step, "overrides": list(overrides), "frames": len(ms["base"]),
            "ms": ms, "median_ms": {k: float(np.median(v)) for k, v in ms.items()},
            "median_ratio": float(np.median(ratio)), "load_average_1min": load}
