"""Local planner on synthetic depth: walls ahead, free space, goals to the side."""

from __future__ import annotations

import numpy as np

from litevloc.base.params.sim import SimParams
from litevloc.base.params.sim_navigation import LocalPlannerParams
from litevloc.sim.local_planner import LocalPlanner, arc_points, obstacle_points

P = SimParams()
LP = LocalPlannerParams()
K = P.intrinsics.K
T_BC = P.T_base_camera


def wall_depth(dist_m: float, x_from: float = -np.inf, x_to: float = np.inf) -> np.ndarray:
    """Depth of a vertical wall `dist_m` ahead of the camera (optical z), covering image
    columns whose ray x/z lies in [x_from, x_to]; other pixels see nothing (NaN)."""
    h, w = P.height, P.width
    u = np.arange(w)[None, :].repeat(h, 0)
    xz = (u - K[0, 2]) / K[0, 0]
    d = np.full((h, w), np.nan, np.float32)
    m = (xz * dist_m >= x_from) & (xz * dist_m <= x_to)
    d[m] = dist_m
    return d


def test_obstacle_points_of_a_wall_lie_ahead_in_the_height_band() -> None:
    pts = obstacle_points(wall_depth(1.5), K, T_BC)
    assert len(pts) > 100
    # the camera is 0.25 m ahead of the base and pitched 5 deg down: the wall is ~1.75 m ahead
    assert 1.55 < np.median(pts[:, 0]) < 1.95
    assert np.ptp(pts[:, 1]) > 1.5  # spans the field of view


def test_free_space_goes_straight_to_the_goal() -> None:
    lp = LocalPlanner()
    c = lp.command(np.array([3.0, 0.0]), np.full((P.height, P.width), np.nan, np.float32), K, T_BC)
    assert c.reason == "arc" and c.v == lp.params.max_speed and abs(c.omega) < 0.1
    c = lp.command(np.array([2.0, 0.8]), None, K, T_BC)  # goal ahead-left -> curve left
    assert c.v > 0 and c.omega > 0.1


def test_wall_ahead_turns_away_and_blocked_stops() -> None:
    lp = LocalPlanner()
    # a wall 2 m ahead covering the right half of the view (camera x >= 0): go left around it
    c = lp.command(np.array([4.0, 0.0]), wall_depth(2.0, x_from=0.0), K, T_BC)
    assert c.reason == "arc" and c.omega > 0.05 and c.v > 0, c
    # mirrored: wall on the left -> turn right
    c = lp.command(np.array([4.0, 0.0]), wall_depth(2.0, x_to=0.0), K, T_BC)
    assert c.reason == "arc" and c.omega < -0.05 and c.v > 0, c
    # without the wall it would go straight
    assert abs(lp.command(np.array([4.0, 0.0]), None, K, T_BC).omega) < 1e-9
    # a wall right in front, everywhere: no admissible arc, turn in place without moving (the
    # local path, off here, would lead around the wall's end: a turn toward it, see below)
    c = LocalPlanner(LocalPlannerParams(grid_radius_m=0)).command(np.array([4.0, 0.1]), wall_depth(0.2), K, T_BC)
    assert c.reason == "blocked" and c.v == 0.0 and c.omega != 0.0
    c = lp.command(np.array([4.0, 0.1]), wall_depth(0.2), K, T_BC)
    assert c.reason == "turn" and c.v == 0.0 and c.omega != 0.0


def test_goal_behind_turns_in_place_and_arrival_stops() -> None:
    lp = LocalPlanner(LocalPlannerParams(turn_in_place_deg=50))
    c = lp.command(np.array([-1.0, 0.5]), None, K, T_BC)
    assert c.reason == "turn" and c.v == 0.0 and c.omega > 0
    assert lp.command(np.array([0.05, 0.0]), None, K, T_BC).reason == "arrived"


def test_arc_points_geometry() -> None:
    assert np.allclose(arc_points(0.0, np.array([1.0]))[-1], [1.0, 0.0])
    # half circle of radius 1 (curvature 1, length pi) ends at (0, 2)
    assert np.allclose(arc_points(1.0, np.array([np.pi]))[-1], [0.0, 2.0], atol=1e-9)


def test_memory_keeps_obstacles_that_left_the_view() -> None:
    lp = LocalPlanner()
    T0 = np.eye(4)
    lp.command(np.array([4.0, 0.0]), wall_depth(1.0, x_from=0.0), K, T_BC, T_odom_base=T0)
    # the robot has turned 90 deg left: nothing in view now, but the wall is remembered on its right
    T1 = np.eye(4)
    T1[:2, :2] = [[0, -1], [1, 0]]
    lp.command(np.array([4.0, 0.0]), np.full((P.height, P.width), np.nan, np.float32), K, T_BC, T_odom_base=T1)
    pts = lp._remember(np.zeros((0, 2)), T1)
    assert len(pts) > 10 and np.median(pts[:, 1]) < -1.0  # to the right (-y) of the turned robot


def _yawed(yaw_deg: float, x: float = 0.0) -> np.ndarray:
    T = np.eye(4)
    a = np.radians(yaw_deg)
    T[:2, :2] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
    T[0, 3] = x
    return T


def test_memory_outlasts_turning_in_place_and_ages_with_net_turning_and_travel() -> None:
    """Seen once, a wall stays known through any number of back-and-forth sweeps in place (net
    heading change ~0: the dithering robot of office-101 forgot its wall after one swing and
    drove the local path through it) and through a full turn; it is forgotten after turning
    one way long enough (net radians x memory_m_per_rad > memory_travel_m) or driving on."""
    lp = LocalPlanner()
    empty = np.full((P.height, P.width), np.nan, np.float32)
    lp.command(np.array([4.0, 0.0]), wall_depth(1.0, x_from=0.0), K, T_BC, T_odom_base=np.eye(4))
    n0 = len(lp._remember(np.zeros((0, 2)), np.eye(4)))
    assert n0 > 10
    sweep = [*range(0, 91, 10), *range(90, -91, -10), *range(-90, 1, 10)]  # 2 pi turned in 10-deg steps
    for yaw in sweep * 5:
        lp.command(np.array([4.0, 0.0]), empty, K, T_BC, T_odom_base=_yawed(yaw))
    pts = lp._remember(np.zeros((0, 2)), np.eye(4))
    assert len(pts) == n0 and np.median(pts[:, 0]) > 0.5  # still ahead of the (unturned) robot
    for yaw in range(10, 361, 10):  # one full turn to the left: 2 pi x memory_m_per_rad < the budget
        lp.command(np.array([4.0, 0.0]), empty, K, T_BC, T_odom_base=_yawed(yaw))
    assert len(lp._remember(np.zeros((0, 2)), np.eye(4))) == n0
    turns = int(np.ceil(LP.memory_travel_m / (2 * np.pi * LP.memory_m_per_rad))) + 1  # their age > the budget
    for yaw in range(390, 360 * turns + 1, 30):
        lp.command(np.array([4.0, 0.0]), empty, K, T_BC, T_odom_base=_yawed(yaw))
    assert len(lp._remember(np.zeros((0, 2)), np.eye(4))) == 0
    lp2 = LocalPlanner()
    lp2.command(np.array([4.0, 0.0]), wall_depth(1.0, x_from=0.0), K, T_BC, T_odom_base=np.eye(4))
    # drive back and forth sideways, staying within the memory radius of the wall: the travel
    # budget alone forgets it, once the metres driven exceed it
    steps = [0.1 * k for k in (*range(1, 6), *range(4, -6, -1), *range(-4, 1))] * 2  # 4 m driven in 0.1 m steps
    n = int(np.ceil((LP.memory_travel_m + 0.1) / 0.1))
    assert n < len(steps)
    for k, y in enumerate(steps[:n]):
        T = np.eye(4)
        T[1, 3] = y
        lp2.command(np.array([4.0, 0.0]), empty, K, T_BC, T_odom_base=T)
        if k == n - 3:
            assert len(lp2._remember(np.zeros((0, 2)), T)) > 10  # still known just under the budget
    assert len(lp2._remember(np.zeros((0, 2)), T)) == 0


def test_an_obstacle_seen_within_the_memory_radius_is_still_known_on_arrival() -> None:
    """A door jamb seen once 2.2 m ahead (then at the image edge, or in a depth hole) is still
    remembered when the robot has driven up to it: the travel budget covers the memory radius.
    With a budget shorter than the distance, it was forgotten on the way and hit."""
    assert LP.memory_travel_m >= LP.memory_radius_m
    lp = LocalPlanner()
    empty = np.full((P.height, P.width), np.nan, np.float32)
    lp.command(np.array([4.0, 0.0]), wall_depth(2.2, x_from=0.0), K, T_BC, T_odom_base=np.eye(4))
    n0 = len(lp._remember(np.zeros((0, 2)), np.eye(4)))
    assert n0 > 10
    for x in np.arange(0.1, 1.85, 0.1):  # 1.8 m driven towards it, blind
        lp.command(np.array([4.0, 0.0]), empty, K, T_BC, T_odom_base=_yawed(0.0, x))
    pts = lp._remember(np.zeros((0, 2)), _yawed(0.0, 1.8))
    assert len(pts) == n0 and np.median(pts[:, 0]) < 0.8  # just ahead of the robot now


def test_bumper_contacts_block_arcs_the_camera_cannot_see() -> None:
    """A door frame touched on the right, out of view: arcs into it are refused afterwards."""
    lp = LocalPlanner()
    T = np.eye(4)
    empty = np.full((P.height, P.width), np.nan, np.float32)
    goal = np.array([1.5, -0.9])  # ahead-right: without contacts the planner curves right
    assert lp.command(goal, empty, K, T_BC, T_odom_base=T).omega < -0.05
    # contacts from the front-right quarter of the robot's outline (a bumper)
    ang = np.radians(np.arange(-80, -10, 10))
    lp.add_contacts(0.32 * np.stack([np.cos(ang), np.sin(ang)], 1), T)
    c = lp.command(goal, empty, K, T_BC, T_odom_base=T)
    assert not (c.reason == "arc" and c.omega < -0.05), c  # no longer into the contact
    # contacts are kept in the odometry frame: after moving 1 m forward they lie behind
    T2 = np.eye(4)
    T2[0, 3] = 1.0
    assert lp.command(np.array([1.5, -0.9]), empty, K, T_BC, T_odom_base=T2).omega < -0.05


def _bumper_ring(angles_deg: np.ndarray) -> np.ndarray:
    """Contact points of the simulated bumper's ring (2 cm outside the 0.3 m robot) at these angles."""
    a = np.radians(angles_deg)
    return 0.32 * np.stack([np.cos(a), np.sin(a)], 1)


def test_after_a_bump_the_robot_backs_up_until_the_contact_ahead_is_clear() -> None:
    """A jamb touched at the front-right (out of view): straight back, one command after the
    other, until the contact lies contact_clear_m beyond the radius (not one step, after which
    an arc went into the same jamb again); then it drives on."""
    lp = LocalPlanner()
    p = lp.params
    empty = np.full((P.height, P.width), np.nan, np.float32)
    T = np.eye(4)
    lp.observe(floor_depth(), K, T_BC, _pose(1.0, np.pi))  # it came this way: the floor behind was seen
    lp.add_contacts(_bumper_ring(np.arange(-50.0, -19.0, 10.0)), T)
    goal = np.array([2.0, -1.0])
    reasons = []
    for _ in range(p.backoff_commands + 2):
        c = lp.command(goal, empty, K, T_BC, T_odom_base=T)
        reasons.append(c.reason)
        if c.reason != "back off":
            break
        assert c.v < 0 and c.omega == 0.0
        T = T.copy()
        T[0, 3] += c.v * 0.2  # 5 Hz commands: 3 cm back each
    ahead = lp.contacts_base(T)
    # nearest contact (20 deg, 0.30 m ahead) must reach 0.40 m: 4 commands of 3 cm
    assert reasons == ["back off"] * 4 + [reasons[-1]] and reasons[-1] != "back off", reasons
    assert np.min(np.hypot(*ahead.T)) >= p.robot_radius + p.contact_clear_m
    # a bump in a corner that backing up cannot clear: at most backoff_commands commands
    lp2 = LocalPlanner()
    lp2.observe(floor_depth(), K, T_BC, _pose(1.0, np.pi))
    lp2.add_contacts(_bumper_ring(np.array([0.0])), np.eye(4))
    backs = [lp2.command(goal, empty, K, T_BC, T_odom_base=np.eye(4)).reason for _ in range(p.backoff_commands + 3)]
    n = p.backoff_commands
    assert backs[:n] == ["back off"] * n and "back off" not in backs[n:], backs


def _drive(T: np.ndarray, v: float, omega: float, dt: float = 0.2, steps: int = 20) -> list[np.ndarray]:
    """Unicycle motion of the base pose T (4x4) for dt seconds: the poses along the way."""
    out = []
    for _ in range(steps):
        yaw = np.arctan2(T[1, 0], T[0, 0]) + omega * dt / steps
        T = T.copy()
        T[:2, 3] += v * dt / steps * np.array([np.cos(yaw), np.sin(yaw)])
        T[:2, :2] = [[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]]
        out.append(T)
    return out


def test_no_arc_comes_closer_to_a_contact_than_the_robot_is() -> None:
    """A jamb touched on the bumper ring just ahead of abreast on the right, the subgoal
    ahead-right past it. Seen by the camera, an arc may come 5 mm closer in such a tight spot;
    as a contact (the jamb itself may lie 3 cm beyond the ring point) no arc may: over a short
    drive the robot never gets closer to the contact than it was when it touched."""
    contact = np.array([[0.06, -0.315]])
    here = float(np.hypot(*contact[0]))
    goal = np.array([1.0, -1.0])
    seen = LocalPlanner()._choose(goal, float(np.hypot(*goal)), contact)
    path = arc_points(seen.omega / seen.v, np.linspace(0.0, 0.2, 100))
    assert seen.reason == "arc" and np.min(np.linalg.norm(path - contact, axis=1)) < here - 1e-3, seen
    touched = LocalPlanner()._choose(goal, float(np.hypot(*goal)), contact, contact)
    if touched.v > 0:
        path = arc_points(touched.omega / touched.v, np.linspace(0.0, 0.2, 100))
        assert np.min(np.linalg.norm(path - contact, axis=1)) >= here - 1e-3, touched
    lp = LocalPlanner()
    T = np.eye(4)
    lp.observe(floor_depth(), K, T_BC, _pose(1.0, np.pi))  # it came this way: the floor behind was seen
    lp.add_contacts(contact, T)
    empty = np.full((P.height, P.width), np.nan, np.float32)
    nearest, reasons = here, []
    for _ in range(25):  # 5 s
        g = np.linalg.inv(T) @ np.array([*goal, 0.0, 1.0])
        c = lp.command(g[:2], empty, K, T_BC, T_odom_base=T)
        reasons.append(c.reason)
        for Tk in _drive(T, c.v, c.omega):
            nearest = min(nearest, float(np.hypot(*(contact[0] - Tk[:2, 3]))))
        T = Tk
    assert nearest >= here - 1e-3, (nearest, reasons)
    assert reasons[0] == "back off" and "arc" in reasons, reasons  # it backs up, then drives on
    assert np.hypot(*(goal - T[:2, 3])) < np.hypot(*goal) - 0.5, (T[:2, 3], reasons)


def test_stuck_without_a_drivable_arc_backs_up_then_tries_again() -> None:
    p = LocalPlannerParams(recover_after=5, recover_commands=3, grid_radius_m=0)
    lp = LocalPlanner(p)
    wall = wall_depth(0.2)  # a wall right in front, everywhere: every arc blocked
    cmds = [lp.command(np.array([4.0, 0.1]), wall, K, T_BC) for _ in range(10)]
    reasons = [c.reason for c in cmds]
    assert reasons[:4] == ["blocked"] * 4
    assert reasons[4:7] == ["recover"] * 3  # 5th blocked command -> straight back for 3 commands
    assert reasons[7:] == ["blocked"] * 3  # then tries again
    assert all(c.v < 0 and c.omega == 0.0 for c in cmds[4:7])
    # arriving resets the count
    lp.command(np.array([0.01, 0.0]), None, K, T_BC)
    assert lp.command(np.array([4.0, 0.1]), wall, K, T_BC).reason == "blocked"



def test_from_a_tight_spot_no_arc_comes_closer_than_the_robot_radius() -> None:
    """A door jamb seen 0.32 m to the front-right (just outside the 0.3 m radius), the subgoal
    past it: the planner may drive an arc that gets 5 mm closer than the robot already is, but
    never one that passes within the robot's radius (the floor's one bump: a tight turn out of a
    doorway that the former rule allowed down to 0.8x the radius)."""
    lp = LocalPlanner()
    jamb = np.array([[0.1, -0.3]])
    c = lp._choose(np.array([1.0, -1.0]), float(np.sqrt(2.0)), jamb)
    assert c.reason == "arc", c
    path = arc_points(c.omega / c.v, np.linspace(0.0, 1.0, 400))
    assert np.min(np.linalg.norm(path - jamb, axis=1)) > lp.params.robot_radius, c


def test_after_being_blocked_arcs_are_tried_before_facing_the_subgoal_again() -> None:
    """A box right in front and the subgoal behind it: once blocked, the planner drives an
    arc around the box for a while instead of turning straight back to face it (the
    floor world's ground-truth run dithered in front of a box for 30 s and gave up)."""
    wall = np.stack([np.full(41, 0.45), np.linspace(-1.0, 1.0, 41)], 1)  # across the whole front
    box = np.stack([np.full(21, 0.8), np.linspace(0.0, 1.0, 21)], 1)  # ahead-left; the right side is open
    side_goal = np.array([0.5, 1.4])  # 70 deg to the left: normally faced by turning in place
    fresh = LocalPlanner()
    assert fresh._choose(side_goal, float(np.hypot(*side_goal)), box).reason == "turn"
    lp = LocalPlanner()
    assert lp._choose(np.array([2.0, 0.3]), 2.0, wall).reason == "blocked"
    c = lp._choose(side_goal, float(np.hypot(*side_goal)), box)
    assert c.reason == "arc" and c.v > 0
    for _ in range(LocalPlannerParams().detour_commands):  # the detour ends: the subgoal is faced again
        c = lp._choose(side_goal, float(np.hypot(*side_goal)), box)
    assert c.reason == "turn"


def floor_depth(wall_m: float = np.inf) -> np.ndarray:
    """Depth of the floor (z = 0 in the base frame) seen by the camera, cut by a vertical wall
    `wall_m` ahead of the camera (optical z) where that is nearer; NaN above the horizon."""
    h, w = P.height, P.width
    v, u = np.mgrid[0:h, 0:w]
    rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones((h, w))], -1)  # optical, z = 1
    R, t = T_BC[:3, :3], T_BC[:3, 3]
    down = (rays @ R.T)[..., 2]  # base-frame z per unit of optical depth
    d = np.where(down < -1e-6, -t[2] / np.minimum(down, -1e-6), np.nan)
    return np.fmin(d, wall_m).astype(np.float32)


def _pose(x: float, yaw: float) -> np.ndarray:
    T = np.eye(4)
    T[:2, :2] = [[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]]
    T[0, 3] = x
    return T


def _recover_after_looking_back(behind: np.ndarray) -> list:
    """The robot looked back from 1 m ahead (seeing `behind`), then stands at the origin facing
    +x with a wall right in front everywhere: its commands while stuck."""
    lp = LocalPlanner(LocalPlannerParams(recover_after=5, recover_commands=3))
    lp.observe(behind, K, T_BC, _pose(1.0, np.pi))
    return [lp.command(np.array([4.0, 0.1]), wall_depth(0.2), K, T_BC, _pose(0.0, 0.0)) for _ in range(10)]


def test_backing_up_needs_the_way_back_clear() -> None:
    """Recovery backs up only where nothing known lies behind: with a wall seen 0.35 m behind the robot it
    turns in place instead (a blind reversal into a wall seen beside the robot, and on into it,
    was a building's 4 ground-truth collisions); over seen floor it backs up."""
    free = _recover_after_looking_back(floor_depth())
    assert [c.reason for c in free[4:7]] == ["recover"] * 3 and all(c.v < 0 for c in free[4:7])
    walled = _recover_after_looking_back(floor_depth(wall_m=1.1))  # 1 - 0.25 - 1.1: 0.35 m behind
    assert all(c.v >= 0 for c in walled), [c.reason for c in walled]
    assert {c.reason for c in walled} <= {"blocked", "turn"}  # turning in place: always collision-free
    lp = LocalPlanner()
    assert lp.rear_clear(np.array([[0.5, 0.0], [0.0, 0.4]])) and not lp.rear_clear(np.array([[-0.38, 0.05]]))


def test_after_backing_up_to_recover_the_robot_faces_the_subgoal_before_driving() -> None:
    """Blocked (a wall everywhere ahead), the robot backs up; then, with the subgoal 70 deg to the
    side, it turns in place to face it. Arcs tried at once (the detour that follows a blocked
    command) drove a robot wedged beside a door straight back into the same spot for 30 s."""
    lp = LocalPlanner(LocalPlannerParams(grid_radius_m=0, recover_after=3, recover_commands=2))
    reasons = [lp.command(np.array([4.0, 0.1]), wall_depth(0.2), K, T_BC).reason for _ in range(4)]
    assert reasons == ["blocked", "blocked", "recover", "recover"], reasons
    side = np.array([np.cos(np.radians(70.0)), np.sin(np.radians(70.0))]) * 2.0
    c = lp.command(side, None, K, T_BC)
    assert c.reason == "turn" and c.v == 0.0 and c.omega > 0, c


def test_remembered_obstacles_the_camera_now_sees_past_are_forgotten() -> None:
    """A person crossing 2 m ahead leaves obstacle points in the memory; the next frame sees the
    floor and a wall 4 m ahead past where they were: forgotten (ray-trace clearing), so people
    walking by leave no trail for the arcs to avoid. Off: the trail stays for memory_travel_m."""
    person = floor_depth(4.0)
    u = np.arange(P.width)[None, :].repeat(P.height, 0)
    person[np.abs((u - K[0, 2]) / K[0, 0]) < 0.15] = 2.0  # camera x within 0.3 m at 2 m: a person's width
    left = floor_depth(4.0)
    for clear, kept in ((True, False), (False, True)):
        lp = LocalPlanner(LocalPlannerParams(clear_seen_through=clear))
        lp.observe(person, K, T_BC, np.eye(4))
        near = lambda pts: int((np.abs(pts[:, 0] - 2.25) < 0.15).sum())  # noqa: E731 (2 m + the camera's 0.25 m)
        assert near(lp._remember(np.zeros((0, 2)), np.eye(4))) > 10
        after = lp.observe(left, K, T_BC, np.eye(4))
        assert (near(after) > 10) == kept, (clear, near(after))
        assert near(after) == 0 or not clear


def test_what_the_camera_does_not_see_now_is_not_forgotten() -> None:
    """Clearing needs free ground seen past a point: nothing in view (NaN depth), a point nearer
    than the lowest ground the camera sees, or one beyond the wall it sees, stays remembered."""
    lp = LocalPlanner()
    lp.observe(wall_depth(2.0), K, T_BC, np.eye(4))
    n0 = len(lp._remember(np.zeros((0, 2)), np.eye(4)))
    lp.observe(np.full((P.height, P.width), np.nan, np.float32), K, T_BC, np.eye(4))
    assert len(lp._remember(np.zeros((0, 2)), np.eye(4))) == n0
    lp.observe(floor_depth(1.5), K, T_BC, np.eye(4))  # a nearer wall hides where the old one was
    pts = lp._remember(np.zeros((0, 2)), np.eye(4))
    assert int((np.abs(pts[:, 0] - 2.25) < 0.15).sum()) > 10
    lp._remember(np.array([[0.4, 0.0]]), np.eye(4))  # at the bumper, under the view's lowest ray
    pts = lp.observe(floor_depth(4.0), K, T_BC, np.eye(4))
    assert np.hypot(*(pts - [0.4, 0.0]).T).min() < 1e-9
