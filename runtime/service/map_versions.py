"""A new version of the map, loaded and verified beside the one in use, and the in-thread VLoc that
can take it between two queries (`runtime.service.map_switch` decides when).

`prepare_localizer` is the whole check a version passes before the service may switch to it, the
same in this process and in the VLoc child process (`runtime.service.vloc_process`): every file
against the manifest (`load_map`), the models (`check_map_models`, as at start-up), and the map frame
(the keyframes both versions hold must agree, `pipelines.topomap.frame_check`). A version that
fails is `MapRefused` with a `MapRefusal` kind; the localizer in use is not touched.
"""

from __future__ import annotations

import dataclasses
import logging
from enum import Enum
from pathlib import Path
from typing import TYPE_CHECKING

from litevloc.base.errors import LiteVLocError
from litevloc.models.registry import ModelError
from litevloc.pipelines.localization.second_look import SecondLook
from litevloc.pipelines.localization.vloc import VisualLocalizer
from litevloc.pipelines.topomap.frame_check import frame_agreement
from litevloc.pipelines.topomap.io import MapFormatError, load_map
from litevloc.pipelines.topomap.types import TopoMap
from litevloc.runtime.vloc_models import ModelBundle, check_map_models, second_look_for

log = logging.getLogger(__name__)

if TYPE_CHECKING:
    from litevloc.config.schema import LiteVLocConfig
    from litevloc.hw.messages import RgbdFrame
    from litevloc.runtime.service.core import VlocOutcome
    from litevloc.runtime.service.vloc_prior import VlocPrior


class MapRefusal(str, Enum):
    """Why a map version was refused (the status's `map.last_refusal`)."""

    LOAD_FAILED = "load_failed"  # missing, unlisted, truncated or corrupt files (`MapFormatError`)
    MODEL_MISMATCH = "model_mismatch"  # built with other models than the service runs
    FRAME_MISMATCH = "frame_mismatch"  # the keyframes both versions hold disagree: another map frame
    VLOC_PROCESS = "vloc_process"  # the VLoc child process failed or died while preparing it


class MapRefused(LiteVLocError, RuntimeError):
    """A map version that cannot be switched to; `kind` says why (branch on it, not on the text)."""

    def __init__(self, kind: MapRefusal, message: str) -> None:
        super().__init__(message)
        self.kind = kind


def prepare_localizer(path: Path, current: TopoMap, bundle: ModelBundle, cfg: LiteVLocConfig,
                      in_use: VisualLocalizer | None = None) -> tuple[TopoMap, VisualLocalizer]:
    """The map at `path` checked against the service's models and `current`'s map frame, and a
    localizer on it (same settings, same models; the second look's extractor shared with `in_use`'s
    when it has one); `MapRefused` naming the problem otherwise."""
    try:
        topomap = load_map(path)
    except (MapFormatError, OSError) as exc:
        raise MapRefused(MapRefusal.LOAD_FAILED, str(exc)) from exc
    try:
        topomap = check_map_models(topomap, bundle)
    except ModelError as exc:
        raise MapRefused(MapRefusal.MODEL_MISMATCH, str(exc)) from exc
    ms = cfg.runtime.map_switch
    agreement = frame_agreement(current, topomap)
    if not agreement.agrees(ms.frame_tolerance_m, ms.frame_tolerance_deg):
        raise MapRefused(MapRefusal.FRAME_MISMATCH, (
            f"{agreement.shared} keyframe(s) both versions hold differ by {agreement.median_m:.3f} m / "
            f"{agreement.median_deg:.2f} deg (median; tolerance {ms.frame_tolerance_m:g} m / "
            f"{ms.frame_tolerance_deg:g} deg): not the same map frame"))
    models = dataclasses.replace(cfg.models, intra_op_threads=cfg.runtime.ort_intra_op_threads)
    lp = cfg.localization
    old_look = None if in_use is None else in_use.local_search.second_look
    if isinstance(old_look, SecondLook):  # its extractor (~70 MB, loaded on first use) serves both versions
        look: SecondLook | None = SecondLook(topomap, lp, old_look.features.extract, bundle.describe,
                                             old_look.local.verifier.match, old_look.first_size)
    else:
        look = second_look_for(topomap, models, lp, bundle)
    localizer = VisualLocalizer(topomap, lp, bundle.extract, bundle.describe, bundle.match, second_look=look)
    return topomap, localizer


def switch_localizer(old: VisualLocalizer, new: VisualLocalizer, t_ns: int) -> VisualLocalizer:
    """`new` continuing `old`'s tracking (`Tracker.carry_over`): call between two queries only. The
    log says what was carried: LL failures carried can end in LOST at the first refusal on the new
    version, as they would have on the old one."""
    new.tracker.carry_over(old.tracker, t_ns, "map version switched")
    log.info("tracking carried across the map switch: %s, %d consecutive LL failures (LOST at %d)",
             new.tracker.state.value, new.tracker.failures, new.tracker.params.local_search.failures_before_lost)
    return new


class ThreadVloc:
    """The service's `vloc(frame, prior)` on a localizer in this process that can take a new map
    version: `prepare_map` (any thread; slow) then `commit_map` (the VLoc thread, between queries)."""

    def __init__(self, topomap: TopoMap, localizer: VisualLocalizer, bundle: ModelBundle,
                 cfg: LiteVLocConfig) -> None:
        from litevloc.runtime.service.shell import localizer_callable

        self._wrap = localizer_callable
        self.topomap, self.localizer, self.bundle, self.cfg = topomap, localizer, bundle, cfg
        self._fn = localizer_callable(localizer)
        self._prepared: tuple[TopoMap, VisualLocalizer] | None = None
        self._last_t_ns = 0

    def __call__(self, frame: RgbdFrame, prior: VlocPrior | None) -> VlocOutcome:
        self._last_t_ns = int(frame.t_ns)
        return self._fn(frame, prior)

    def prepare_map(self, path: Path) -> int:
        """Load and verify the version at `path` (`prepare_localizer`); its node count. MapRefused."""
        topomap, localizer = prepare_localizer(path, self.topomap, self.bundle, self.cfg, self.localizer)
        self._prepared = (topomap, localizer)
        return topomap.n_nodes

    def commit_map(self) -> None:
        """Switch to the prepared version (the VLoc thread, between two queries)."""
        if self._prepared is None:
            raise RuntimeError("commit_map without a prepared map")
        topomap, new = self._prepared
        self._prepared = None
        self.localizer = switch_localizer(self.localizer, new, self._last_t_ns)
        self.topomap, self._fn = topomap, self._wrap(self.localizer)

    def discard_map(self) -> None:
        """Drop a prepared version not switched to."""
        self._prepared = None
