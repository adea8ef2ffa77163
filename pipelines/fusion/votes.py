"""When VLoc poses agree: the initialisation and re-anchoring votes of `OnlineFusion`, and
whether a late pose may still be carried into the window (see its module docstring)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from litevloc.base.geometry import invert, rotation_angle
from litevloc.base.params.fusion import FusionParams
from litevloc.pipelines.fusion.odometry_buffer import OdometryBuffer

F64 = NDArray[np.float64]

AGREE_SIGMAS = 3.0  # how far two VLoc poses may differ by the odometry's drift between them


@dataclass
class Candidate:
    """A VLoc pose as fusion takes it: `T_map_base` and the odometry `T_odom_base` at its capture
    time `t_ns`, `cov` 6x6 in GTSAM order (base frame)."""

    t_ns: int
    T_map_base: F64
    T_odom_base: F64
    cov: F64  # gtsam order

    def carried_to(self, other: Candidate) -> F64:
        """This pose carried by the odometry to `other`'s capture time (T_map_base)."""
        return self.T_map_base @ invert(self.T_odom_base) @ other.T_odom_base


def agree(cands: list[Candidate], odom: OdometryBuffer, p: FusionParams) -> bool:
    """Whether every pose, carried by the odometry to the newest one's capture time, lies
    within `init_max_trans_m` / `init_max_rot_deg` of it, widened by three sigmas of the
    odometry's drift over the path between them (`FusionParams.drift_sigmas`). Compared
    where the robot is, not as T_map_odom: a small heading difference moves T_map_odom's
    origin by the robot's distance from it."""
    ref = cands[-1]
    for c in cands[:-1]:
        if c.t_ns < odom.first_t:  # the odometry between them has left the buffer
            return False
        yaw, along, side = p.drift_sigmas(odom.path(c.t_ns, ref.t_ns)[0])
        pos = along + side
        E = invert(ref.T_map_base) @ c.carried_to(ref)
        if (
            float(np.linalg.norm(E[:3, 3])) > p.init_max_trans_m + AGREE_SIGMAS * pos
            or rotation_angle(E[:3, :3]) > math.radians(p.init_max_rot_deg) + AGREE_SIGMAS * yaw
        ):
            return False
    return True


def combines(old: Candidate, new: Candidate, odom: OdometryBuffer, p: FusionParams) -> bool:
    """Whether an earlier vote may combine with a new one: captured within `init_window_s`, or
    the odometry between them travelled less than `init_window_m` and turned less than
    `init_window_deg` (a global localization slower than the window, on a robot waiting)."""
    if new.t_ns - old.t_ns <= p.init_window_s * 1e9:
        return True
    if old.t_ns < odom.first_t:  # its odometry has left the buffer
        return False
    return odom.within(old.t_ns, new.t_ns, p.init_window_m, p.init_window_deg)


def carried_late(path_m: float, path_rad: float, p: FusionParams) -> bool:
    """Whether a pose captured before the window may be carried to its oldest state by the
    buffered odometry, which drove `path_m` and turned `path_rad` since the capture: less
    than `late_max_travel_m` and `late_max_turn_deg` (the carrying adds that odometry's
    noise to the pose's covariance, `graph_ops.carried_cov`)."""
    return p.late_max_travel_m > 0 and path_m < p.late_max_travel_m and path_rad < math.radians(
        p.late_max_turn_deg)
