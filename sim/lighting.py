"""Lighting of a changed building, baked into its textures: daylight of another hour, lamps
switched, camera exposure. Only colours change; geometry and depth stay as generated.

* daylight: light through the windows at another hour comes from another direction; a face
  whose normal points towards the sun's azimuth gets brighter, the opposite faces darker
  (gain `1 + daylight * cos(normal - azimuth)`);
* lamps: in some regions the lamps were switched (off: `LAMP_OFF_GAIN`, on where the mapping
  run had them off: `LAMP_ON_GAIN`) on its walls, furniture, floor and ceiling;
* exposure: one gain over the whole building (the camera's auto-exposure settles elsewhere).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from litevloc.sim.elements import Face

LAMP_OFF_GAIN = 0.6
LAMP_ON_GAIN = 1.3
DAYLIGHT_PER_LEVEL = 0.35
EXPOSURE_EV_PER_LEVEL = 0.6


@dataclass(frozen=True)
class LightingChange:
    """A drawn lighting change: sun azimuth (rad, world frame), daylight strength, lamp gain per
    region label (regions not listed: 1), and the exposure gain."""

    sun_azimuth: float
    daylight: float
    lamps: dict[int, float]
    exposure: float

    def face_gains(self, faces: list[Face], face_region: list[int]) -> NDArray[np.float32]:
        """(F,) colour gain of each face; `face_region[i]`: the region it lights (walls: its
        own, box faces: the region under the box)."""
        normal_angle = np.array([(0.0 if f.normal > 0 else np.pi) if f.axis == 0 else
                                 (np.pi / 2 if f.normal > 0 else -np.pi / 2) for f in faces])
        day = 1.0 + self.daylight * np.cos(normal_angle - self.sun_azimuth)
        lamp = np.array([self.lamps.get(r, 1.0) for r in face_region])
        return (day * lamp * self.exposure).astype(np.float32).reshape(-1)

    def region_gain(self, labels: NDArray[np.int32]) -> NDArray[np.float32]:
        """Gain (same shape as `labels`) of floor and ceiling over a label grid."""
        gain = np.full(labels.shape, self.exposure, np.float32)
        for label, g in self.lamps.items():
            gain[labels == label] *= np.float32(g)
        return gain

    def summary(self) -> dict[str, object]:
        return {"sun_azimuth_deg": float(np.degrees(self.sun_azimuth)), "daylight": self.daylight,
                "lamps": {str(k): v for k, v in sorted(self.lamps.items())}, "exposure": self.exposure}


def draw_lighting(region_labels: list[int], level: float, rng: np.random.Generator) -> LightingChange:
    """The lighting change of `level` in [0, 1]: daylight `DAYLIGHT_PER_LEVEL * level` from a
    drawn azimuth, lamps switched in `level / 2` of the regions, exposure within
    +-`EXPOSURE_EV_PER_LEVEL * level` EV."""
    azimuth = float(rng.uniform(-np.pi, np.pi))
    n = round(level / 2 * len(region_labels))
    picked = rng.permutation(len(region_labels))[:n]
    lamps = {int(region_labels[int(i)]): LAMP_OFF_GAIN if rng.random() < 0.6 else LAMP_ON_GAIN for i in picked}
    exposure = float(2.0 ** (rng.uniform(-1.0, 1.0) * EXPOSURE_EV_PER_LEVEL * level))
    return LightingChange(azimuth, DAYLIGHT_PER_LEVEL * level, lamps, exposure)
