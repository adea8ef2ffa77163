"""Closed-loop navigation in the simulator: the loop's rates and limits, the simulated robot's
local planner and its search for a first pose (config section `sim_navigation`, used by
`litevloc.runtime.tools.sim_navigation`, `litevloc.sim.local_planner` and `litevloc.sim.search`)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from litevloc.base.settings import Settings, section, setting


@dataclass(frozen=True)
class LocalPlannerParams(Settings):
    """The simulated robot's reactive planner: arcs scored on depth-derived obstacle points.

    Obstacle memory: points are kept in the odometry frame while they stay within
    `memory_radius_m` and were seen less than `memory_travel_m` of odometry ago (metres driven
    since, plus `memory_m_per_rad` per radian of net heading change since: turning back and
    forth in place keeps them), so odometry drift cannot move them far. A remembered point the
    camera now sees past (free ground beyond it along its column) is forgotten
    (`clear_seen_through`, a costmap's ray-trace clearing): people walking by leave no trails.
    Recovery: after `recover_after` commands without a drivable arc (e.g. diagonally in a
    doorway) the robot backs straight up for `recover_commands` commands, each only while the
    `rear_check_m` behind it is clear of known obstacles and of ground not seen (as arcs are),
    then faces the point it steers to before driving (no detour first: arcs at once drive it back into the spot).
    Detour: after a blocked command, arcs are tried for `detour_commands` commands even when the
    subgoal is far to the side, so an obstacle in front of a subgoal is driven around.
    Local path: known obstacle points are rasterised on a `grid_m` grid out to `grid_radius_m`;
    the arcs steer to the farthest path point within `lookahead_m` that a straight line from the
    robot reaches with clearance (at least `carrot_m` along the path)."""

    max_speed: float = setting(
        0.6, "top forward speed of the local planner (at least min_speed)", unit="m/s", low=0, low_open=True)
    min_speed: float = setting(
        0.15, "lowest speed of a driven arc, also the backing-up speed", unit="m/s", low=0, low_open=True)
    max_omega: float = setting(1.0, "top turn rate", unit="rad/s", low=0, low_open=True)
    max_curvature: float = setting(2.5, "arcs have curvatures in [-this, this]", unit="1/m", low=0, low_open=True)
    n_arcs: int = setting(21, "arcs tried per command", low=3)
    lookahead_m: float = setting(2.5, "arcs are checked this far, or to the subgoal", unit="m", low=0, low_open=True)
    samples: int = setting(25, "points checked along each arc", low=2)
    time_to_end_s: float = setting(
        1.5, "speed = free arc length / this, clipped to [min_speed, max_speed]", unit="s", low=0, low_open=True)
    min_progress_m: float = setting(0.2, "arcs blocked sooner than this are not driven", unit="m", low=0)
    robot_radius: float = setting(0.3, "radius of the robot's footprint", unit="m", low=0, low_open=True)
    margin_m: float = setting(
        0.03, "arcs closer to an obstacle than robot_radius + this are blocked (clearance_m is the soft term)",
        unit="m", low=0)
    unseen_overlap_m: float = setting(
        0.05, "arcs may sweep the robot's footprint this far over ground its camera never saw (>= robot_radius: off)",
        unit="m", low=-math.inf)
    height_band_m: tuple[float, float] = setting(
        (0.08, 1.5), "obstacle heights above the floor, [low, high] with low < high", unit="m", low=-math.inf)
    max_range_m: float = setting(4.0, "depth farther than this is not an obstacle", unit="m", low=-math.inf)
    stride_px: int = setting(4, "depth image subsampling for obstacle points", unit="px", low=1)
    turn_in_place_deg: float = setting(
        55.0, "turn in place when the subgoal's bearing exceeds this", unit="deg", low=-math.inf)
    turn_gain: float = setting(
        1.5, "turn rate per radian of bearing to the subgoal when turning in place", unit="1/s", low=-math.inf)
    arrive_m: float = setting(0.15, "stop when the subgoal is this close", unit="m", low=-math.inf)
    clearance_m: float = setting(0.7, "clearance below this is penalised", unit="m", low=-math.inf)
    w_clearance: float = setting(3.0, "weight of the clearance penalty in an arc's score", low=-math.inf)
    w_turn: float = setting(0.1, "weight of an arc's curvature in its score", low=-math.inf)
    memory_radius_m: float = setting(
        2.5, "remembered obstacle points farther from the robot than this are dropped", unit="m", low=0, low_open=True)
    memory_travel_m: float = setting(
        2.5, "remembered obstacle points seen more than this much odometry ago are dropped (0: no memory)", unit="m",
        low=0)
    memory_m_per_rad: float = setting(
        0.1, "a radian of net heading change since a sighting counts as this many metres of odometry", unit="m/rad",
        low=0)
    clear_seen_through: bool = setting(
        True, "remembered obstacle points on ground the current depth image sees free (its column reaches past "
        "them) are forgotten, as a costmap's ray-trace clearing: moving people leave no trails")
    voxel_m: float = setting(0.05, "obstacle points are thinned to one per voxel of this size", unit="m", low=-math.inf)
    contact_points: int = setting(64, "bumper contacts remembered in the odometry frame, newest kept", low=-math.inf)
    contact_clear_m: float = setting(
        0.1, "after a bump, back up until the nearest contact ahead is this far beyond robot_radius", unit="m", low=0)
    backoff_commands: int = setting(8, "commands spent backing off after a bump at most", low=0)
    recover_after: int = setting(15, "consecutive commands without a drivable arc before backing up", low=-math.inf)
    recover_commands: int = setting(8, "commands spent backing up", low=-math.inf)
    rear_check_m: float = setting(
        0.1, "before each backing-up command the footprint's path this far straight back is checked", unit="m", low=0,
        low_open=True)
    detour_commands: int = setting(
        10, "commands after a blocked one during which arcs are tried even towards a subgoal far to the side",
        low=-math.inf)
    grid_m: float = setting(0.05, "cell of the local path grid", unit="m", low=0, low_open=True)
    grid_radius_m: float = setting(
        3.0, "the local path grid reaches this far around the robot (0: arcs steer straight to the subgoal)", unit="m",
        low=0)
    path_clear_m: float = setting(
        0.6, "cells nearer an obstacle than this cost proportionally more on the local path", unit="m", low=-math.inf)
    blocked_cost: float = setting(40.0, "extra cost of a cell nearer an obstacle than robot_radius + margin_m", low=0)
    carrot_m: float = setting(
        0.8, "the arcs steer at least this far along the local path", unit="m", low=0, low_open=True)

    def check_relations(self) -> None:
        if not self.min_speed <= self.max_speed:
            raise ValueError("need 0 < min_speed <= max_speed")
        if not self.height_band_m[0] < self.height_band_m[1]:
            raise ValueError("height_band_m must be (low, high) with low < high")


@dataclass(frozen=True)
class SearchParams(Settings):
    """Looking for a first pose: turn on the spot, then drive to open space not yet visited
    (`litevloc.sim.search`)."""

    omega: float = setting(0.5, "turn rate while looking around for a first pose", unit="rad/s", low=0, low_open=True)
    look_rad: float = setting(
        2 * np.pi, "turn this far at each search spot before moving on", unit="rad", low=0, low_open=True)
    leg_m: float = setting(
        1.5, "drive at most this far to the next search spot (at least min_leg_m)", unit="m", low=0, low_open=True)
    min_leg_m: float = setting(
        0.4, "search headings with less free length than this are not taken", unit="m", low=0, low_open=True)
    stop_short_m: float = setting(0.6, "a search leg stops this far before the first obstacle ahead", unit="m", low=0)
    margin_m: float = setting(
        0.05, "the corridor checked for free length is robot radius + this on each side", unit="m", low=0)
    range_m: float = setting(
        8.0, "free length of a search heading is measured this far", unit="m", low=0, low_open=True)
    novelty_weight: float = setting(
        1.0, "weight of novelty (distance from the spots already visited) in a heading's score", low=0)
    novelty_cap_m: float = setting(2.0, "novelty counts up to this distance", unit="m", low=0)
    leg_timeout_s: float = setting(
        15.0, "a search leg ends after this much simulated time", low=0, low_open=True, unit="s")
    leg_blocked_commands: int = setting(10, "a search leg ends after this many blocked commands", low=1)

    def check_relations(self) -> None:
        if not self.min_leg_m <= self.leg_m:
            raise ValueError("need 0 < min_leg_m <= leg_m")


@dataclass(frozen=True)
class NavParams(Settings):
    """The closed loop `litevloc sim navigate` runs: simulator -> runtime -> planner -> local planner."""

    control_hz: float = setting(
        5.0, "local planner and simulator step rate; a frame is rendered each step", unit="Hz", low=0, low_open=True,
        high=50)
    vloc_hz: float = setting(
        1.0, "frames handed to the runtime per simulated second (at most control_hz)", unit="Hz", low=0, low_open=True)
    goal_timeout_s: float = setting(
        120.0, "simulated seconds per goal before it is cancelled", unit="s", low=0, low_open=True)
    goal_timeout_s_per_m: float = setting(
        4.0, "a goal also gets at least this per metre of the shortest free path from where it became active to its "
        "place (0: off)", unit="s/m", low=0)
    success_radius_m: float = setting(
        2.0, "a goal is reached within this of its place; goals are localized to a map keyframe, often 1-2 m away",
        unit="m", low=0, low_open=True)
    search_after_s: float = setting(
        3.0, "with no pose yet for this long, look for a place: turn, then move (simulated s)", unit="s", low=-math.inf)
    answer_timeout_s: float = setting(
        20.0, "wall time to wait for the planner's answer to a pose", unit="s", low=0, low_open=True)
    seed: int = setting(0, "seed of the simulated run (noise, drift) and of the goal images' lighting", low=-math.inf)
    odometry_hz: float | None = setting(
        50.0, "simulated odometry rate, the loop's message load: each fused pose goes to the planner (null: sim's)",
        unit="Hz", low=-math.inf)
    local: LocalPlannerParams = section(LocalPlannerParams, "the simulated robot's local planner")
    search: SearchParams = section(SearchParams, "the search for a first pose")

    def check_relations(self) -> None:
        if not self.vloc_hz <= self.control_hz:
            raise ValueError("need 0 < vloc_hz <= control_hz <= 50")
