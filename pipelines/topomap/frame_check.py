"""Whether two versions of a map share one map frame: the keyframes both hold, compared.

`map update` and `map merge` keep the parent map's frame (merge puts the second map into
the first's), so a keyframe that both versions hold (the same capture stamp) has the same
`T_map_camera` in both, up to what an update re-optimises. A map built from another session
without alignment has its own frame, and the shared keyframes (if any) disagree by metres.
Maps without a shared keyframe cannot be compared this way (`shared == 0`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from litevloc.base.geometry import relative_pose_error
from litevloc.pipelines.topomap.types import TopoMap


@dataclass(frozen=True)
class FrameAgreement:
    """The keyframes two maps share (same `t_ns`) and how far their poses differ: medians over
    them of the translation (metres) and rotation (degrees) difference; NaN where none is shared."""

    shared: int
    median_m: float
    median_deg: float

    def agrees(self, tolerance_m: float, tolerance_deg: float) -> bool:
        """True unless shared keyframes disagree by more than a tolerance (nothing shared: True)."""
        return self.shared == 0 or (self.median_m <= tolerance_m and self.median_deg <= tolerance_deg)


def frame_agreement(old: TopoMap, new: TopoMap) -> FrameAgreement:
    """Compare the poses of the keyframes `old` and `new` both hold (matched by capture stamp)."""
    _, i_old, i_new = np.intersect1d(np.asarray(old.t_ns), np.asarray(new.t_ns), return_indices=True)
    if len(i_old) == 0:
        return FrameAgreement(0, float("nan"), float("nan"))
    pairs = zip(i_old, i_new, strict=True)
    errs = np.array([relative_pose_error(old.T_map_camera[a], new.T_map_camera[b]) for a, b in pairs])
    return FrameAgreement(len(i_old), float(np.median(errs[:, 0])), float(np.median(errs[:, 1])))
