"""Closed-loop navigation in the simulator: the loop's rates and limits, the simulated robot's
local planner and its search for a first pose (config section `sim_navigation`, used by
`litevloc.runtime.tools.sim_navigation`, `litevloc.sim.local_planner` and `litevloc.sim.search`)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class LocalPlannerParams:
    """The simulated robot's reactive planner: arcs scored on depth-derived obstacle points.

    Obstacle memory: points are kept in the odometry frame while they stay within
    `memory_radius_m` and were seen less than `memory_travel_m` of odometry ago (metres driven
    since, plus `memory_m_per_rad` per radian of net heading change since: turning back and
    forth in place keeps them), so odometry drift cannot move them far.
    Recovery: after `recover_after` commands without a drivable arc (e.g. diagonally in a
    doorway) the robot backs straight up for `recover_commands` commands, each only while the
    `rear_check_m` behind it is clear of known obstacles and of ground not seen (as arcs are),
    then faces the point it steers to before driving (no detour: arcs tried at once drove it back).
    Detour: after a blocked command, arcs are tried for `detour_commands` commands even when the
    subgoal is far to the side, so an obstacle in front of a subgoal is driven around.
    Local path: known obstacle points are rasterised on a `grid_m` grid out to `grid_radius_m`;
    the arcs steer to the farthest path point within `lookahead_m` that a straight line from the
    robot reaches with clearance (at least `carrot_m` along the path)."""

    # top forward speed (m/s)
    max_speed: float = 0.6
    # lowest speed of a driven arc, also the backing-up speed (m/s)
    min_speed: float = 0.15
    # top turn rate (rad/s)
    max_omega: float = 1.0
    # arcs have curvatures in [-this, this] (1/m)
    max_curvature: float = 2.5
    # arcs tried per command
    n_arcs: int = 21
    # arcs are checked this far, or to the subgoal (m)
    lookahead_m: float = 2.5
    # points checked along each arc
    samples: int = 25
    # speed = free arc length / this, clipped to [min_speed, max_speed] (s)
    time_to_end_s: float = 1.5
    # arcs blocked sooner than this are not driven (m)
    min_progress_m: float = 0.2
    # radius of the robot's footprint (m)
    robot_radius: float = 0.3
    # arcs closer to an obstacle than robot_radius + this are blocked (m; clearance_m is the soft term)
    margin_m: float = 0.03
    # arcs may sweep the robot's footprint this far over ground its camera never saw (m; >= robot_radius: off)
    unseen_overlap_m: float = 0.05
    # obstacle heights above the floor, [low, high] (m)
    height_band_m: tuple[float, float] = (0.08, 1.5)
    # depth farther than this is not an obstacle (m)
    max_range_m: float = 4.0
    # depth image subsampling (pixels)
    stride_px: int = 4
    # turn in place when the subgoal's bearing exceeds this (degrees)
    turn_in_place_deg: float = 55.0
    # turn rate per radian of bearing to the subgoal when turning in place (1/s)
    turn_gain: float = 1.5
    # stop when the subgoal is this close (m)
    arrive_m: float = 0.15
    # clearance below this is penalised (m)
    clearance_m: float = 0.7
    # weight of the clearance penalty in an arc's score
    w_clearance: float = 3.0
    # weight of an arc's curvature in its score
    w_turn: float = 0.1
    # remembered obstacle points farther from the robot than this are dropped (m)
    memory_radius_m: float = 2.5
    # remembered obstacle points seen more than this much odometry ago are dropped (m; 0: no memory)
    memory_travel_m: float = 2.5
    # a radian of net heading change since a sighting counts as this many metres of odometry (m/rad)
    memory_m_per_rad: float = 0.1
    # obstacle points are thinned to one per voxel of this size (m)
    voxel_m: float = 0.05
    # bumper contacts remembered in the odometry frame, newest kept
    contact_points: int = 64
    # after a bump, back up until the nearest contact ahead is this far beyond robot_radius (m)
    contact_clear_m: float = 0.1
    # commands spent backing off after a bump at most
    backoff_commands: int = 8
    # consecutive commands without a drivable arc before backing up
    recover_after: int = 15
    # commands spent backing up
    recover_commands: int = 8
    # before each backing-up command the footprint's path this far straight back is checked (m)
    rear_check_m: float = 0.1
    # commands after a blocked one during which arcs are tried even towards a subgoal far to the side
    detour_commands: int = 10
    # cell of the local path grid (m)
    grid_m: float = 0.05
    # the local path grid reaches this far around the robot (m; 0: arcs steer straight to the subgoal)
    grid_radius_m: float = 3.0
    # cells nearer an obstacle than this cost proportionally more on the local path (m)
    path_clear_m: float = 0.6
    # extra cost of a cell nearer an obstacle than robot_radius + margin_m
    blocked_cost: float = 40.0
    # the arcs steer at least this far along the local path (m)
    carrot_m: float = 0.8

    def __post_init__(self) -> None:
        if not 0 < self.min_speed <= self.max_speed:
            raise ValueError("need 0 < min_speed <= max_speed")
        if self.max_omega <= 0 or self.max_curvature <= 0 or self.n_arcs < 3 or self.samples < 2:
            raise ValueError("need max_omega > 0, max_curvature > 0, n_arcs >= 3 and samples >= 2")
        if self.lookahead_m <= 0 or self.time_to_end_s <= 0 or self.min_progress_m < 0:
            raise ValueError("need lookahead_m > 0, time_to_end_s > 0 and min_progress_m >= 0")
        if self.robot_radius <= 0 or self.margin_m < 0 or self.stride_px < 1:
            raise ValueError("need robot_radius > 0, margin_m >= 0 and stride_px >= 1")
        if self.memory_radius_m <= 0 or self.memory_travel_m < 0 or self.memory_m_per_rad < 0:
            raise ValueError("need memory_radius_m > 0, memory_travel_m >= 0 and memory_m_per_rad >= 0")
        if not self.height_band_m[0] < self.height_band_m[1]:
            raise ValueError("height_band_m must be (low, high) with low < high")
        if self.grid_m <= 0 or self.grid_radius_m < 0 or self.carrot_m <= 0 or self.blocked_cost < 0:
            raise ValueError("need grid_m > 0, grid_radius_m >= 0, carrot_m > 0 and blocked_cost >= 0")
        if self.contact_clear_m < 0 or self.backoff_commands < 0:
            raise ValueError("need contact_clear_m >= 0 and backoff_commands >= 0")
        if self.rear_check_m <= 0:
            raise ValueError("need rear_check_m > 0")


@dataclass(frozen=True)
class SearchParams:
    """Looking for a first pose: turn on the spot, then drive to open space not yet visited
    (`litevloc.sim.search`)."""

    # turn rate while looking around (rad/s)
    omega: float = 0.5
    # turn this far at each spot before moving on (rad)
    look_rad: float = 2 * np.pi
    # drive at most this far to the next spot (m)
    leg_m: float = 1.5
    # headings with less free length than this are not taken (m)
    min_leg_m: float = 0.4
    # stop this far before the first obstacle ahead (m)
    stop_short_m: float = 0.6
    # the corridor checked for free length is robot radius + this on each side (m)
    margin_m: float = 0.05
    # free length is measured this far (m)
    range_m: float = 8.0
    # weight of novelty (distance from the spots already visited) in a heading's score
    novelty_weight: float = 1.0
    # novelty counts up to this distance (m)
    novelty_cap_m: float = 2.0
    # a leg ends after this long (simulated s)
    leg_timeout_s: float = 15.0
    # a leg ends after this many blocked commands
    leg_blocked_commands: int = 10

    def __post_init__(self) -> None:
        if self.omega <= 0 or self.look_rad <= 0 or self.leg_timeout_s <= 0 or self.range_m <= 0:
            raise ValueError("need omega > 0, look_rad > 0, leg_timeout_s > 0 and range_m > 0")
        if not 0 < self.min_leg_m <= self.leg_m or self.stop_short_m < 0 or self.margin_m < 0:
            raise ValueError("need 0 < min_leg_m <= leg_m, stop_short_m >= 0 and margin_m >= 0")
        if self.novelty_weight < 0 or self.novelty_cap_m < 0 or self.leg_blocked_commands < 1:
            raise ValueError("need novelty_weight >= 0, novelty_cap_m >= 0 and leg_blocked_commands >= 1")


@dataclass(frozen=True)
class NavParams:
    """The closed loop `litevloc sim navigate` runs: simulator -> runtime -> planner -> local planner."""

    # local planner and simulator step rate; a frame is rendered each step (Hz)
    control_hz: float = 5.0
    # frames handed to the runtime per simulated second (Hz)
    vloc_hz: float = 1.0
    # simulated seconds per goal before it is cancelled (s)
    goal_timeout_s: float = 120.0
    # and at least this per metre of the shortest free path from where the goal became active to its place (s/m; 0: off)
    goal_timeout_s_per_m: float = 4.0
    # a goal is reached within this of its place; goals are localized to a map keyframe, often 1-2 m away (m)
    success_radius_m: float = 2.0
    # with no pose yet for this long, look for a place: turn, then move (simulated s)
    search_after_s: float = 3.0
    # wall time to wait for the planner's answer to a pose (s)
    answer_timeout_s: float = 20.0
    # seed of the simulated run (noise, drift) and of the goal images' lighting
    seed: int = 0
    # simulated odometry rate, the loop's message load: each fused pose goes to the planner (Hz; null: sim's)
    odometry_hz: float | None = 50.0
    # the simulated robot's local planner
    local: LocalPlannerParams = field(default_factory=LocalPlannerParams)
    # the search for a first pose
    search: SearchParams = field(default_factory=SearchParams)

    def __post_init__(self) -> None:
        if not (0 < self.control_hz <= 50 and 0 < self.vloc_hz <= self.control_hz):
            raise ValueError("need 0 < vloc_hz <= control_hz <= 50")
        if self.goal_timeout_s <= 0 or self.success_radius_m <= 0 or self.answer_timeout_s <= 0:
            raise ValueError("goal_timeout_s, success_radius_m and answer_timeout_s must be > 0")
        if self.goal_timeout_s_per_m < 0:
            raise ValueError(f"goal_timeout_s_per_m must be >= 0, got {self.goal_timeout_s_per_m}")
