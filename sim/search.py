"""Looking for a first fix: turn in place, then move to open space and look again (demo code).

A robot that has never localized cannot be given a path, so it has to find a view the map
knows. Turning in place is enough where the start spot faces something the mapping pass
saw; where it does not (the `bland` world's start, 1 m from the mapping pass's keyframes and
facing a bookshelf they never saw: no heading localizes, while 0.7 m toward the room's middle
several do), the robot has to move. `LocalizationSearch` alternates:

* **look**: turn in place for `look_rad` (one full turn by default), noting for each
  heading how far the robot could drive straight ahead (the nearest depth obstacle point
  within the robot's half-width plus `margin_m`, up to `range_m`);
* **move**: drive, with the local planner (so obstacles are avoided), toward the spot
  up to `leg_m` (stopping `stop_short_m` before the first obstacle) along the heading that
  scores best: its free length (open space: the middle of a room, a door, where a mapping
  pass most likely went) plus `novelty_weight` x the spot's distance from the places
  already looked from (capped at `novelty_cap_m`), so the search spreads out instead of
  going back and forth. A leg ends on arrival, after `leg_timeout_s`, or when the local planner has been
  blocked for `leg_blocked_commands` commands; then the robot looks again.

Pure: inputs are odometry (`T_odom_base`), the depth image and the time; output a command.
The robot's integration (here the simulator driver) uses it while it has no pose at all;
once a pose arrives the planner's subgoals take over.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from litevloc.base.params.sim_navigation import SearchParams
from litevloc.sim.local_planner import Command, LocalPlanner, obstacle_points


def free_length(pts_base: NDArray[np.floating], half_width_m: float, max_range_m: float) -> float:
    """How far (m) the robot can drive straight ahead: the nearest of the (M, 2) obstacle
    points (base frame, x forward) ahead of it within `half_width_m` of its centre line, or
    `max_range_m` when none is."""
    p = np.asarray(pts_base, np.float64).reshape(-1, 2)
    ahead = p[(p[:, 0] > 0) & (np.abs(p[:, 1]) <= half_width_m)]
    return float(min(ahead[:, 0].min(), max_range_m)) if len(ahead) else float(max_range_m)


def _xy_yaw(T_odom_base: NDArray[np.floating]) -> tuple[NDArray[np.float64], float]:
    T = np.asarray(T_odom_base, np.float64)
    return T[:2, 3].copy(), float(np.arctan2(T[1, 0], T[0, 0]))


class LocalizationSearch:
    """Look around, then move to open space, until the caller stops asking (see module doc)."""

    def __init__(self, planner: LocalPlanner, params: SearchParams = SearchParams()) -> None:
        self.planner, self.params = planner, params
        self.visited: list[NDArray[np.float64]] = []  # (2,) odometry-frame spots looked from
        self.phase = "look"
        self._turned = 0.0
        self._last_yaw: float | None = None
        self._headings: list[tuple[float, float]] = []  # (yaw in the odometry frame, free length m)
        self.target: NDArray[np.float64] | None = None  # (2,) odometry frame, while moving
        self._leg_start_s = 0.0
        self._blocked = 0
        self.legs = 0

    def _choose_leg(self, xy: NDArray[np.float64]) -> NDArray[np.float64] | None:
        """The next spot (odometry frame) from the headings seen in this look, or None."""
        p = self.params
        best, best_score = None, -np.inf
        for yaw, free in self._headings:
            length = min(free - p.stop_short_m, p.leg_m)
            if length < p.min_leg_m:
                continue
            end = xy + length * np.array([np.cos(yaw), np.sin(yaw)])
            novelty = min((float(np.hypot(*(end - v))) for v in self.visited), default=p.novelty_cap_m)
            score = free + p.novelty_weight * min(novelty, p.novelty_cap_m)
            if score > best_score:
                best, best_score = end, score
        return best

    def command(self, t_s: float, T_odom_base: NDArray[np.floating], depth: NDArray[np.floating] | None,
                K: NDArray[np.floating], T_base_camera: NDArray[np.floating]) -> Command:
        """The next (v, omega) at sensor time `t_s` (s); `T_odom_base` 4x4 odometry pose,
        `depth` HxW metres in the camera at `T_base_camera` (None: nothing seen this step)."""
        p, lp = self.params, self.planner.params
        xy, yaw = _xy_yaw(T_odom_base)
        if self.phase == "move":
            assert self.target is not None
            g = self.target - xy
            c, s = np.cos(yaw), np.sin(yaw)
            g_base = np.array([c * g[0] + s * g[1], -s * g[0] + c * g[1]])
            cmd = self.planner.command(g_base, depth, K, T_base_camera, T_odom_base)
            self._blocked = self._blocked + 1 if cmd.reason in ("blocked", "recover") else 0
            if cmd.reason != "arrived" and t_s - self._leg_start_s < p.leg_timeout_s and \
                    self._blocked < p.leg_blocked_commands:
                return Command(cmd.v, cmd.omega, "search-" + cmd.reason, cmd.clearance_m)
            self.phase, self._turned, self._last_yaw, self._headings = "look", 0.0, None, []
        if self._last_yaw is None:
            if not self.visited or np.hypot(*(xy - self.visited[-1])) > p.min_leg_m / 2:
                self.visited.append(xy)  # a new spot to look from (not the same after a look found no way)
        else:
            self._turned += abs(float(np.angle(np.exp(1j * (yaw - self._last_yaw)))))
        self._last_yaw = yaw
        pts = self.planner.observe(depth, K, T_base_camera, T_odom_base)  # keeps its obstacle memory current
        if depth is not None:
            far = obstacle_points(depth, K, T_base_camera, replace(lp, max_range_m=p.range_m))
            free = free_length(np.concatenate([pts, far]), lp.robot_radius + p.margin_m, p.range_m)
            self._headings.append((yaw, free))
        if self._turned >= p.look_rad:
            target = self._choose_leg(xy)
            self._turned, self._last_yaw, self._headings = 0.0, None, []
            if target is not None:
                self.phase, self.target, self._leg_start_s, self._blocked = "move", target, t_s, 0
                self.legs += 1
                return self.command(t_s, T_odom_base, depth, K, T_base_camera)
        return Command(0.0, p.omega, "search-look")
