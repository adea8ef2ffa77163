"""The GTSAM `OnlineFusion` as the core's `FusionPort`: the messages it takes, the orders they come in."""

from __future__ import annotations

from typing import TYPE_CHECKING

from litevloc.hw.messages import Odometry
from litevloc.runtime.service.core import FusedPoseLike, FusionPort, FusionUpdateLike, VlocOutcome

if TYPE_CHECKING:
    from litevloc.pipelines.fusion.online import OnlineFusion


def fusion_port(fusion: OnlineFusion, defer_updates: bool = False) -> FusionPort:
    """An object with `add_odometry(t_ns, T_odom_base, covariance)` and
    `add_vloc(t_ns, T_map_camera, covariance, vote_only=False)` (the GTSAM `OnlineFusion`) -> the
    core's `FusionPort`; a rejected result with a provisional pose goes in as a vote.
    The VLoc covariance is passed as `pipelines.pnp` gives it:
    6x6, camera-frame right perturbation, order (tx, ty, tz, rx, ry, rz). Fused covariances are
    already in ROS order.

    `defer_updates`: odometry that makes a fusion keyframe due returns its pose before the
    smoother update, which `after_odometry` (`fusion.flush()`) runs once the pose was handed on."""

    def on_odometry(o: Odometry) -> FusedPoseLike | None:
        if defer_updates:
            return fusion.add_odometry(o.t_ns, o.T_odom_base, o.covariance, defer_update=True)
        return fusion.add_odometry(o.t_ns, o.T_odom_base, o.covariance)

    def on_vloc(r: VlocOutcome) -> FusionUpdateLike:
        prov = r.provisional
        if not r.accepted and prov is not None:  # a provisional GL pose: a vote
            return fusion.add_vloc(r.t_ns, prov.T_map_camera, prov.covariance, vote_only=True)
        if r.T_map_camera is None:
            raise ValueError(f"VLoc result at t={r.t_ns} ns is accepted but has no pose")
        return fusion.add_vloc(r.t_ns, r.T_map_camera, r.covariance)

    return FusionPort(on_odometry, on_vloc, fusion.flush if defer_updates else None)
