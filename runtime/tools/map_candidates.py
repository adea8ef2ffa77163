"""The map service's push gate: build a candidate version from a robot's push with the existing
`map merge` / `map update` algorithms, then publish it only if the held-out check (global
localization of held-out posed frames, as `bench/update.py` measures a map update) is not
worse than with the current version.

* a pushed session map (kind "map") is merged into the current version's frame
  (`pipelines.topomap.merge.merge_sessions`); the first version of a map is the pushed map
  itself, checked by loading it;
* a pushed recording (kind "recording") updates the current version
  (`pipelines.topomap.session.update_from_session`, as `litevloc map update`);
* "not worse": the candidate localizes at least as many held-out frames as the current version,
  and its median position error is at most `median_tolerance_m` larger.
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from litevloc.base.geometry import relative_pose_error
from litevloc.config.schema import LiteVLocConfig
from litevloc.pipelines.topomap.io import load_map
from litevloc.pipelines.topomap.map_save import save_map
from litevloc.pipelines.topomap.merge import MapMergeError, merge_sessions
from litevloc.pipelines.topomap.types import TopoMap
from litevloc.runtime.maps.server import PushVerdict
from litevloc.runtime.tools.posed import posed_frames

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class HeldOutScore:
    """Global localization of the held-out frames: `accepted` of `queries`, median position error
    (metres) of the accepted ones (NaN when none)."""

    queries: int
    accepted: int
    median_m: float

    def to_json(self) -> dict[str, Any]:
        return {"queries": self.queries, "accepted": self.accepted,
                "median_m": None if np.isnan(self.median_m) else self.median_m}


def not_worse(candidate: HeldOutScore, current: HeldOutScore, median_tolerance_m: float) -> tuple[bool, str]:
    """(accept, one-line reason) of the held-out comparison."""
    if candidate.accepted < current.accepted:
        return False, (f"held-out check worse: {candidate.accepted}/{candidate.queries} frames localized, the current "
                       f"version {current.accepted}/{current.queries}")
    if candidate.accepted and current.accepted and candidate.median_m > current.median_m + median_tolerance_m:
        return False, (f"held-out check worse: median error {100 * candidate.median_m:.1f} cm, the current version "
                       f"{100 * current.median_m:.1f} cm (tolerance {100 * median_tolerance_m:.1f} cm)")
    return True, (f"held-out check not worse: {candidate.accepted}/{candidate.queries} localized (current "
                  f"{current.accepted}/{current.queries})")


class HeldOutGate:
    """A `runtime.maps.server.PushGate` over the held-out recording `held_out` (posed frames)."""

    def __init__(self, cfg: LiteVLocConfig, held_out: Path, frames: slice = slice(None),
                 median_tolerance_m: float = 0.01) -> None:
        from litevloc.runtime.vloc_models import load_bundle

        self.cfg, self.held_out, self.frames = cfg, Path(held_out), frames
        self.median_tolerance_m = float(median_tolerance_m)
        self.bundle = load_bundle(cfg.models)
        self._scores: dict[str, HeldOutScore] = {}  # by the current version's folder: versions never change

    def score(self, m: TopoMap) -> HeldOutScore:
        from litevloc.pipelines.localization.vloc import VisualLocalizer
        from litevloc.runtime.sources import open_source
        from litevloc.runtime.vloc_models import check_map_models, second_look_for

        m = check_map_models(m, self.bundle)
        loc = VisualLocalizer(m, self.cfg.localization, self.bundle.extract, self.bundle.describe, self.bundle.match,
                              second_look=second_look_for(m, self.cfg.models, self.cfg.localization, self.bundle))
        src = open_source(self.held_out, self.frames, strict=True, rgbd_calibration=self.cfg.rgbd_calibration)
        errs: list[float] = []
        n = 0
        for frame, T in posed_frames(src):
            if T is None:
                continue
            n += 1
            res = loc.localize_global(frame.t_ns, frame.color, frame.depth, frame.K)
            if res.accepted and res.T_map_camera is not None:
                errs.append(float(relative_pose_error(res.T_map_camera, T)[0]))
        if n == 0:
            raise ValueError(f"{self.held_out}: no posed frames to check maps with")
        return HeldOutScore(n, len(errs), float(np.median(errs)) if errs else float("nan"))

    def prepare(self, current: Path, loaded: TopoMap | None = None) -> HeldOutScore:
        """Score the version in folder `current` (`loaded`: that map, already read) now and keep the
        score (versions never change): a push against it then scores only its candidate. A service
        does this when a version becomes latest, or pays for it on the first push."""
        key = str(current)
        if key not in self._scores:
            self._scores[key] = self.score(load_map(current) if loaded is None else loaded)
        return self._scores[key]

    def __call__(self, name: str, current: Path | None, upload: Path, kind: str, out: Path) -> PushVerdict:
        t0 = time.perf_counter()
        if current is None:
            if kind != "map":
                return PushVerdict(False, f"map {name!r} has no version yet: push a map folder first")
            save_map(load_map(upload), out, descriptor_bytes=self.cfg.mapping.descriptor_bytes)
            score = self.score(load_map(out))
            return PushVerdict(score.accepted > 0, f"first version of {name!r}: {score.accepted}/{score.queries} "
                               "held-out frames localized", {"candidate": score.to_json()})
        base = load_map(current)
        try:
            cand, build = self._merge(base, upload) if kind == "map" else self._update(base, upload)
        except (MapMergeError, ValueError) as exc:
            return PushVerdict(False, f"candidate not built: {exc}")
        cur = self.prepare(current, base)
        # the check reads the candidate as it will be served: saved (descriptors encoded) and loaded back
        cand.meta.update({"parent_map": name, "fleet_push": json.dumps(build)})
        save_map(cand, out, descriptor_bytes=self.cfg.mapping.descriptor_bytes)
        new = self.score(load_map(out))
        ok, reason = not_worse(new, cur, self.median_tolerance_m)
        details = {"current": cur.to_json(), "candidate": new.to_json(), "build": build,
                   "seconds": time.perf_counter() - t0}
        log.info("push to %s: %s", name, reason)
        return PushVerdict(ok, reason, details)

    def _merge(self, base: TopoMap, upload: Path) -> tuple[TopoMap, dict[str, Any]]:
        from litevloc.runtime.vloc_models import check_map_models

        other = check_map_models(load_map(upload), self.bundle)
        merged, report, _alignment, _ = merge_sessions(check_map_models(base, self.bundle), other, self.bundle.match,
                                                       self.cfg.mapping.merge)
        return merged, {"kind": "merge", "nodes_before": base.n_nodes, "nodes_after": merged.n_nodes,
                        "links_consistent": report.links_consistent, "nodes_dropped": report.nodes_dropped}

    def _update(self, base: TopoMap, recording: Path) -> tuple[TopoMap, dict[str, Any]]:
        from litevloc.pipelines.localization.vloc import VisualLocalizer
        from litevloc.pipelines.topomap.session import OncePerImage, SessionFrame, update_from_session
        from litevloc.runtime.sources import open_source
        from litevloc.runtime.vloc_models import check_map_models, second_look_for

        m = check_map_models(base, self.bundle)
        extract, describe = OncePerImage(self.bundle.extract), OncePerImage(self.bundle.describe)
        loc = VisualLocalizer(m, self.cfg.localization, extract, describe, self.bundle.match,
                              second_look=second_look_for(m, self.cfg.models, self.cfg.localization, self.bundle))

        def frames() -> Iterator[SessionFrame]:
            src = open_source(recording, slice(None), strict=True, rgbd_calibration=self.cfg.rgbd_calibration)
            for f, T in posed_frames(src):
                yield SessionFrame(f.t_ns, f.index, f.color, f.depth, f.K, f.color_jpeg, T)

        res = update_from_session(m, frames, loc, extract, describe, self.bundle.match, self.cfg.mapping)
        return res.new_map, {"kind": "update", "nodes_before": base.n_nodes, "nodes_after": res.new_map.n_nodes,
                             "added": len(res.report.added), "retired": len(res.report.retired),
                             "compared": res.compared, "frames": res.frames}
