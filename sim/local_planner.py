"""A non-learning local planner for the simulated robot (demo code, not the onboard runtime).

In the spirit of LiteVLoc's navigation experiments, which pair the global subgoal with a
simple local planner: the current depth image is turned into obstacle points on the
ground plane (base frame), a fan of constant-(v, omega) arcs (motion primitives) is
rolled out over a short horizon, arcs that pass within the robot radius plus a margin
of an obstacle point are discarded, and the remaining arc whose end lands closest to the
subgoal (with penalties for low clearance and turning) is driven. A subgoal far to the
side or behind is first faced by turning in place. The arcs do not steer to the subgoal itself
but to the farthest point of the cheapest path to it (on a local grid of the known obstacles,
inflated by the robot's radius; unknown space counts as free) that is in straight, clear line
from the robot, at least `carrot_m` along it: a subgoal behind a wall next to
a door is then reached through the middle of the door, where arcs aimed straight at it ran into
the jamb, turned away and came back (dithering at doors). The camera only sees ahead (and nothing
closer than its minimum depth), so obstacle points are kept in the odometry frame as a rolling
local map (one point per voxel, the newest sighting wins) while they are within
`memory_radius_m` of the robot and were seen less than `memory_travel_m` of odometry ago:
metres driven since the sighting plus `memory_m_per_rad` per radian of *net* heading change
since it (unwrapped, so a full turn counts whole), so that drift stays a few cm. Net, not
summed: a robot turning back and forth in place (a wall behind it, the subgoal flipping sides)
keeps the wall it can no longer see, where a count of every radian turned forgot it after one
swing and the local path then ran through it; a yaw-rate scale error, the drift of turning in
place, also cancels on the way back. A door jamb seen on the way in likewise stays known.
A remembered point on ground the current image sees free, past it along its column, is
forgotten (`clear_seen_through`, a costmap's ray-trace clearing): a person walking across the
view otherwise left a wall of points across the corridor for `memory_travel_m` of driving.
Contacts (a bumper: where the robot touched something, `add_contacts`) are kept the same way
and block arcs like seen obstacles: a door frame beside the robot, which the forward camera
cannot see, is otherwise driven into again and again. After a bump the robot backs up until
the contact ahead is `contact_clear_m` beyond its radius, and no arc may come closer to a contact
than the robot already is (nor within robot_radius + margin_m): a turn toward the next subgoal in
a doorway otherwise picked an arc into the jamb it had just touched (seen obstacles may be
approached 5 mm in a tight spot; contacts, stored on a ring just outside the robot, may not).
Backing up (after a bump, or to recover when no arc is drivable) is blind: the camera looks
ahead. Each backing-up command is given only while the footprint's path `rear_check_m` straight
back keeps off the known obstacles and contacts (by the arcs' rule) and off ground not seen;
otherwise the robot turns in place instead: backing into a wall it had seen beside it, and on
into it for the rest of the recovery, were a building's 4 collisions with ground-truth localization.
Ground the camera looked at is remembered the same way (`seen_ground`), and no arc may sweep the
footprint more than `unseen_overlap_m` over ground not seen: turning into a door from beside it,
the robot's inner side otherwise swung into a jamb that never was in the 72-degree view.

Frames: `base_link` x forward, y left, z up on the floor; the depth image is in the camera
optical frame mounted at `T_base_camera`.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from litevloc.base.params.sim_navigation import LocalPlannerParams
from litevloc.sim.seen_ground import (
    ColumnView,
    column_view,
    grid_lookup,
    local_grid_cells,
    seen_ray_points,
    seen_through,
    unseen_distance,
)


@dataclass(frozen=True)
class Command:
    v: float  # m/s
    omega: float  # rad/s
    reason: str  # "arc" | "turn" | "arrived" | "blocked" | "squeeze" | "recover" | "back off"
    clearance_m: float = float("inf")


def obstacle_points(
    depth: NDArray[np.floating], K: NDArray[np.floating], T_base_camera: NDArray[np.floating],
    params: LocalPlannerParams = LocalPlannerParams(),
) -> NDArray[np.float64]:
    """(M, 2) x, y (base frame, m) of depth points within the obstacle height band.

    depth: HxW float32 metres (NaN / <= 0 invalid); K: 3x3; T_base_camera: 4x4.
    """
    s = params.stride_px
    d = np.asarray(depth, np.float64)[::s, ::s]
    v, u = np.mgrid[0 : depth.shape[0] : s, 0 : depth.shape[1] : s]
    ok = np.isfinite(d) & (d > 0.05) & (d < params.max_range_m)
    z = d[ok]
    x = (u[ok] - K[0, 2]) / K[0, 0] * z
    y = (v[ok] - K[1, 2]) / K[1, 1] * z
    T = np.asarray(T_base_camera, np.float64)
    P = np.stack([x, y, z], 1) @ T[:3, :3].T + T[:3, 3]
    lo, hi = params.height_band_m
    keep = (P[:, 2] > lo) & (P[:, 2] < hi)
    return P[keep, :2]


def arc_points(curvature: float, lengths: NDArray[np.floating]) -> NDArray[np.float64]:
    """(n, 2) points at arc lengths `lengths` (m) along a circle of signed curvature (1/m,
    + = left) leaving the origin along +x."""
    s = np.asarray(lengths, np.float64)
    if abs(curvature) < 1e-9:
        return np.stack([s, np.zeros_like(s)], 1)
    r = 1.0 / curvature
    return np.stack([r * np.sin(s / r), r * (1 - np.cos(s / r))], 1)


class _RecentPoints:
    """(M, 2) points in the odometry frame, one per `voxel_m` cell (the newest sighting wins), each
    with the odometry travel (m) and unwrapped heading (rad) at its sighting."""

    def __init__(self, voxel_m: float) -> None:
        self.voxel_m = voxel_m
        self.pts = np.zeros((0, 2))
        self.driven = np.zeros(0)
        self.heading = np.zeros(0)

    def merge(self, new: NDArray[np.float64], driven: float, heading: float, xy: NDArray[np.float64],
              params: LocalPlannerParams) -> None:
        """Add this frame's `new` (N, 2, odometry frame) seen at (`driven`, `heading`) and drop the
        points farther than `memory_radius_m` from the robot at `xy` or older than `memory_travel_m`."""
        p = params
        pts = np.concatenate([new, self.pts])
        drv = np.concatenate([np.full(len(new), driven), self.driven])
        hdg = np.concatenate([np.full(len(new), heading), self.heading])
        age = driven - drv + p.memory_m_per_rad * np.abs(heading - hdg)
        keep = (np.hypot(*(pts - xy).T) <= p.memory_radius_m) & (age <= p.memory_travel_m)
        idx = np.flatnonzero(keep)[_voxel_firsts(pts[keep], self.voxel_m)]  # this frame's points come first
        self.pts, self.driven, self.heading = pts[idx], drv[idx], hdg[idx]

    def drop(self, gone: NDArray[np.bool_]) -> None:
        """Forget the points where `gone` (M,) is true."""
        keep = ~np.asarray(gone, bool)
        self.pts, self.driven, self.heading = self.pts[keep], self.driven[keep], self.heading[keep]


class LocalPlanner:
    """Chooses (v, omega) toward a subgoal from one depth image (see module docstring)."""

    def __init__(self, params: LocalPlannerParams = LocalPlannerParams()) -> None:
        self.params = p = params
        self.kappas = np.linspace(-p.max_curvature, p.max_curvature, p.n_arcs)
        self.s = np.linspace(p.lookahead_m / p.samples, p.lookahead_m, p.samples)
        self.arcs = np.stack([arc_points(k, self.s) for k in self.kappas])  # (A, n, 2)
        # 2 cm steps up to the second sample: where a contact is checked between the coarse samples
        fine = np.arange(0.02, self.s[min(1, p.samples - 1)], 0.02)
        self.fine_arcs = np.stack([arc_points(k, fine) for k in self.kappas])  # (A, f, 2)
        self.rear = arc_points(0.0, -np.arange(0.02, p.rear_check_m + 1e-9, 0.02))  # (r, 2) straight back
        self._obstacles = _RecentPoints(p.voxel_m)  # obstacle points, odometry frame
        self._seen = _RecentPoints(p.grid_m)  # ground the camera looked at, odometry frame
        self._driven = 0.0  # metres driven so far (odometry)
        self._heading = 0.0  # unwrapped odometry heading (rad): net turning, full turns counted
        self._last_pose: NDArray[np.float64] | None = None  # x, y, yaw (odometry)
        self._turn_sign = 0.0  # while blocked, keep turning the same way (no dithering)
        self.contacts = np.zeros((0, 2))  # (C, 2) bumper contact points, odometry frame
        self._stuck = 0  # consecutive commands without a drivable arc
        self._detour = 0  # commands left in which arcs are tried whatever the subgoal's bearing
        self._reversing = 0  # recovery commands left
        self._backing = 0  # back-off commands left after a bump (0: none)

    def add_contacts(self, pts_base: NDArray[np.floating], T_odom_base: NDArray[np.floating]) -> None:
        """Remember (N, 2) contact points (base frame, m) as obstacles, stored in the odometry
        frame (`T_odom_base` 4x4); the newest `contact_points` are kept. A bump: the next commands
        back off until clear (see `back_off`)."""
        T = np.asarray(T_odom_base, np.float64)
        pts = np.asarray(pts_base, np.float64).reshape(-1, 2) @ T[:2, :2].T + T[:2, 3]
        self.contacts = np.concatenate([self.contacts, pts])[-self.params.contact_points:]
        if len(pts):
            self._backing = self.params.backoff_commands

    def contacts_base(self, T_odom_base: NDArray[np.floating] | None) -> NDArray[np.float64]:
        """(C, 2) the remembered contacts in the base frame (m); none without `T_odom_base`."""
        if T_odom_base is None or not len(self.contacts):
            return np.zeros((0, 2))
        T = np.asarray(T_odom_base, np.float64)
        return np.asarray((self.contacts - T[:2, 3]) @ T[:2, :2], np.float64)

    def back_off(self, contacts: NDArray[np.float64], rear_clear: bool = True) -> Command | None:
        """After a bump: back straight up at `min_speed` while one of the `contacts` (C, 2, base
        frame) ahead of the robot's centre lies nearer than `contact_clear_m` beyond its radius,
        for at most `backoff_commands` commands (every forward arc would come closer to a
        contact ahead), and while the way back is clear (`rear_clear`); None: clear, blocked
        behind, or nothing to back off from."""
        p = self.params
        ahead = contacts[contacts[:, 0] > 0]
        if self._backing > 0 and rear_clear and len(ahead) and \
                float(np.sqrt(np.min((ahead**2).sum(1)))) < p.robot_radius + p.contact_clear_m:
            self._backing -= 1
            return Command(-p.min_speed, 0.0, "back off")
        self._backing = 0
        return None

    @property
    def memory(self) -> NDArray[np.float64]:
        """(M, 2) remembered obstacle points, odometry frame (m)."""
        return self._obstacles.pts

    def _odom_pose(self, T_odom_base: NDArray[np.floating]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(R 2x2, xy) of the robot in the odometry frame; advances the travel and net heading."""
        T = np.asarray(T_odom_base, np.float64)
        c, s_ = T[0, 0], T[1, 0]
        R = np.array([[c, -s_], [s_, c]]) / max(float(np.hypot(c, s_)), 1e-12)
        xy = T[:2, 3].copy()
        yaw = float(np.arctan2(s_, c))
        if self._last_pose is not None:
            self._heading += float(np.angle(np.exp(1j * (yaw - self._last_pose[2]))))
            self._driven += float(np.hypot(*(xy - self._last_pose[:2])))
        self._last_pose = np.array([xy[0], xy[1], yaw])
        return R, xy

    def _remember(self, pts_base: NDArray[np.float64], T_odom_base: NDArray[np.floating],
                  seen_base: NDArray[np.float64] | None = None, view: ColumnView | None = None) -> NDArray[np.float64]:
        """Merge this frame's (N, 2) obstacle points and (S, 2) seen ground points (base frame)
        into the rolling local maps (odometry frame), first forgetting the remembered obstacle points
        `view` (this frame's `column_view`) sees past; returns every remembered obstacle point in
        the base frame."""
        R, xy = self._odom_pose(T_odom_base)
        if view is not None and len(self._obstacles.pts):
            self._obstacles.drop(seen_through(view, (self._obstacles.pts - xy) @ R))
        self._obstacles.merge(pts_base @ R.T + xy, self._driven, self._heading, xy, self.params)
        if seen_base is not None:
            self._seen.merge(seen_base @ R.T + xy, self._driven, self._heading, xy, self.params)
        return np.asarray((self._obstacles.pts - xy) @ R, dtype=np.float64)

    @property
    def _seen_rule_on(self) -> bool:
        """Whether arcs keep off ground not seen: needs the memory, and an overlap under the radius."""
        p = self.params
        return p.memory_travel_m > 0 and p.unseen_overlap_m < p.robot_radius

    def seen_base(self, T_odom_base: NDArray[np.floating] | None) -> NDArray[np.float64] | None:
        """(S, 2) remembered seen ground in the base frame (m); None without `T_odom_base` or
        with the rule off (`unseen_overlap_m` >= robot_radius)."""
        if T_odom_base is None or not self._seen_rule_on:
            return None
        T = np.asarray(T_odom_base, np.float64)
        return np.asarray((self._seen.pts - T[:2, 3]) @ T[:2, :2], np.float64)

    def _thin(self, pts: NDArray[np.float64]) -> NDArray[np.float64]:
        return pts[_voxel_firsts(pts, self.params.voxel_m)]

    def observe(
        self, depth: NDArray[np.floating] | None, K: NDArray[np.floating], T_base_camera: NDArray[np.floating],
        T_odom_base: NDArray[np.floating] | None = None,
    ) -> NDArray[np.float64]:
        """Take in one depth image (HxW metres, None = nothing seen) and return every obstacle
        point the planner knows, (M, 2) in the base frame: this frame's, the rolling memory's
        (with `T_odom_base`) and the bumper contacts. `command` calls it; call it directly to
        keep the memory current while something else steers."""
        p = self.params
        pts = np.zeros((0, 2)) if depth is None else self._thin(obstacle_points(depth, K, T_base_camera, p))
        if T_odom_base is not None and p.memory_travel_m > 0:
            view = looked = None
            if depth is not None:
                view = column_view(depth, K, T_base_camera, p)
                looked = seen_ray_points(view, p) if self._seen_rule_on else None
            pts = self._remember(pts, T_odom_base, looked, view if p.clear_seen_through else None)
        return np.concatenate([pts, self.contacts_base(T_odom_base)])

    def command(
        self, goal_xy: NDArray[np.floating], depth: NDArray[np.floating] | None, K: NDArray[np.floating],
        T_base_camera: NDArray[np.floating], T_odom_base: NDArray[np.floating] | None = None,
    ) -> Command:
        """goal_xy: (2,) subgoal in the base frame (m); depth None = no obstacle information;
        T_odom_base (4x4, odometry) enables the short-term obstacle memory."""
        p = self.params
        g = np.asarray(goal_xy, np.float64)[:2]
        pts = self.observe(depth, K, T_base_camera, T_odom_base)
        dist = float(np.hypot(*g))
        if dist < p.arrive_m:
            self._stuck = self._reversing = 0
            return Command(0.0, 0.0, "arrived")
        contacts = self.contacts_base(T_odom_base)
        seen = self.seen_base(T_odom_base)
        unseen = None if seen is None else unseen_distance(seen, p)
        rear_clear = self.rear_clear(pts, unseen)
        backing = self.back_off(contacts, rear_clear)
        if backing is not None:
            return backing
        if self._reversing > 0 and rear_clear:
            self._reversing -= 1
            return Command(-p.min_speed, 0.0, "recover")
        self._reversing = 0  # done, or blocked behind: what the arcs say (a turn in place at worst)
        g = self.carrot(g, pts)
        cmd = self._choose(g, float(np.hypot(*g)), pts, contacts, unseen)
        self._stuck = 0 if cmd.reason in ("arc", "squeeze") else self._stuck + 1
        if self._stuck >= p.recover_after:
            self._stuck, self._turn_sign = 0, 0.0
            if rear_clear:
                self._detour = 0  # face the point steered to first: arcs at once drive back into the spot
                self._reversing = p.recover_commands - 1
                return Command(-p.min_speed, 0.0, "recover")
        return cmd

    def rear_clear(self, pts: NDArray[np.float64], unseen: NDArray[np.float64] | None = None) -> bool:
        """Whether backing straight up `rear_check_m` keeps the footprint off the obstacle points
        `pts` (M, 2, base frame, contacts included; by the arcs' rule, `_limit`) and, with the
        local grid's distance to ground not seen (`unseen`), off that ground as an arc must."""
        p = self.params
        if len(pts) and bool((_nearest(self.rear[None], pts) <= self._limit(pts)).any()):
            return False
        return unseen is None or \
            bool((grid_lookup(unseen, self.rear, p.grid_m) >= p.robot_radius - p.unseen_overlap_m).all())

    def _limit(self, pts: NDArray[np.float64]) -> float:
        """How near (m) a driven path may come to the obstacle points `pts` (M, 2, base frame):
        robot_radius + margin_m, or from a tight spot (a doorway) 5 mm closer than the robot
        already is, but never within the radius + 5 mm (obstacle points are thinned to voxels: a
        tighter arc clipped a door jamb on the floor world)."""
        p = self.params
        here = float(np.sqrt(np.min((pts**2).sum(1)))) if len(pts) else np.inf
        return min(p.robot_radius + p.margin_m, max(here - 0.005, p.robot_radius + 0.005))

    def carrot(self, g: NDArray[np.float64], pts: NDArray[np.float64]) -> NDArray[np.float64]:
        """Where the arcs should steer (2,): the farthest point of the cheapest local-grid path
        from the robot to the subgoal `g` (base frame, m; a subgoal beyond the grid: to where
        the straight line to it leaves the grid) in clear straight line from the robot, given
        the obstacle points `pts` (M, 2); `g` itself when there are no obstacles, the grid is
        off or the subgoal is nearer than `carrot_m`."""
        p = self.params
        dist = float(np.hypot(*g))
        if p.grid_radius_m <= 0 or len(pts) == 0 or dist <= p.carrot_m:
            return g
        from skimage.graph import route_through_array

        ij, n = local_grid_cells(pts, p.grid_radius_m, p.grid_m)
        c = n // 2
        free = np.full((n, n), 255, np.uint8)
        free[ij[:, 0], ij[:, 1]] = 0
        clear = cv2.distanceTransform(free, cv2.DIST_L2, 5) * p.grid_m
        cost = 1.0 + p.blocked_cost * (clear <= p.robot_radius + p.margin_m) \
            + 4.0 * np.clip(p.path_clear_m - clear, 0.0, None) / p.path_clear_m
        end = g * min(1.0, 0.95 * p.grid_radius_m / dist)
        e = (round(end[1] / p.grid_m) + c, round(end[0] / p.grid_m) + c)
        idx, _ = route_through_array(cost, (c, c), e, fully_connected=True, geometric=True)
        cells = np.asarray(idx, np.int64)
        path = (cells[:, ::-1] - c) * p.grid_m
        along = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(path, axis=0).T))])
        k_min = min(int(np.searchsorted(along, p.carrot_m)), len(path) - 1)
        k_max = int(np.searchsorted(along, p.lookahead_m, side="right")) - 1
        for k in range(max(k_max, k_min), k_min, -1):
            t = np.linspace(0.0, 1.0, max(2, int(along[k] / p.grid_m) + 1))
            ray = np.round(t[:, None] * cells[k] + (1 - t[:, None]) * c).astype(np.int64)
            if np.all(clear[ray[:, 0], ray[:, 1]] > p.robot_radius + p.margin_m) or \
                    np.all(clear[ray[1:, 0], ray[1:, 1]] >= clear[c, c]):  # from a tight spot: no closer
                return np.asarray(path[k], np.float64) if k < len(path) - 1 or dist > 0.95 * p.grid_radius_m \
                    else g
        return np.asarray(path[k_min], np.float64)

    def _choose(self, g: NDArray[np.float64], dist: float, pts: NDArray[np.float64],
                contacts: NDArray[np.float64] | None = None, unseen: NDArray[np.float64] | None = None) -> Command:
        """Turn, an arc, a squeeze or blocked, from the subgoal `g` (base frame, `dist` m away),
        the obstacle points `pts` (M, 2, base frame, contacts included), the bumper
        `contacts` (C, 2, base frame; none: no contact rule) and the local grid's distance to
        ground not seen (`seen_ground.unseen_distance`; none: unknown ground counts as free)."""
        p = self.params
        bearing = float(np.arctan2(g[1], g[0]))
        if abs(bearing) > np.radians(p.turn_in_place_deg) and self._detour == 0:
            return Command(0.0, float(np.clip(p.turn_gain * bearing, -p.max_omega, p.max_omega)), "turn")
        self._detour = max(0, self._detour - 1)
        need = min(dist, p.lookahead_m)
        n_need = int(np.searchsorted(self.s, need - 1e-9)) + 1  # samples up to the subgoal
        arcs = self.arcs[:, :n_need]
        dmin = _nearest(arcs, pts)  # (A, n)
        hit = dmin <= self._limit(pts)  # blocked where an arc comes too near an obstacle
        if contacts is not None and len(contacts):  # a contact: never closer than the robot is now
            here_c = float(np.sqrt(np.min((contacts**2).sum(1))))
            limit_c = min(here_c, p.robot_radius + p.margin_m) - 1e-6
            hit |= _nearest(arcs, contacts) < limit_c
            hit[:, 0] |= (_nearest(self.fine_arcs, contacts) < limit_c).any(axis=1)  # the next command's stretch
        if unseen is not None:  # the footprint may not cover ground the camera never saw
            hit |= grid_lookup(unseen, arcs, p.grid_m) < p.robot_radius - p.unseen_overlap_m
        first = np.where(hit.any(axis=1), hit.argmax(axis=1), n_need)  # first blocked sample
        free_len = np.where(first > 0, self.s[np.maximum(first - 1, 0)], 0.0)
        free_len = np.minimum(free_len, need)
        ok = free_len >= min(p.min_progress_m, need) - 1e-9
        ok &= first > 0
        if not ok.any():
            if first.max() >= 3:  # squeeze: the arc that stays free longest, slowly
                a = int(np.argmax(first - 0.01 * np.abs(self.kappas)))
                return Command(p.min_speed, float(np.clip(self.kappas[a] * p.min_speed, -p.max_omega, p.max_omega)),
                               "squeeze")
            if self._turn_sign == 0.0:
                self._turn_sign = 1.0 if bearing >= 0 else -1.0
            self._detour = p.detour_commands
            return Command(0.0, self._turn_sign * 0.6 * p.max_omega, "blocked")
        self._turn_sign = 0.0
        idx = np.arange(len(self.kappas))
        ends = arcs[idx, np.maximum(first - 1, 0)]
        clear = np.array([dmin[a, : max(first[a], 1)].min() for a in idx])
        cost = (np.linalg.norm(ends - g, axis=1)
                + p.w_clearance * np.maximum(0.0, p.clearance_m - np.minimum(clear, 10.0))
                + p.w_turn * np.abs(self.kappas))
        cost[~ok] = np.inf
        a = int(np.argmin(cost))
        v = float(np.clip(free_len[a] / p.time_to_end_s, p.min_speed, p.max_speed))
        w = float(self.kappas[a] * v)
        if abs(w) > p.max_omega:
            v *= p.max_omega / abs(w)
            w = float(np.sign(w) * p.max_omega)
        return Command(v, w, "arc", float(clear[a]))


def _voxel_firsts(pts: NDArray[np.float64], voxel_m: float) -> NDArray[np.intp]:
    """Indices (ascending) of the first of the (M, 2) points in each `voxel_m` cell."""
    if len(pts) == 0:
        return np.zeros(0, np.intp)
    cell = np.floor(pts / voxel_m).astype(np.int64)
    _, idx = np.unique((cell[:, 0] << 32) + (cell[:, 1] & 0xFFFFFFFF), return_index=True)  # one key per cell
    return np.sort(idx)


def _nearest(arcs: NDArray[np.float64], pts: NDArray[np.float64]) -> NDArray[np.float64]:
    """(A, n) distance (m) from each of the arcs' (A, n, 2) points to the nearest of `pts` (M, 2);
    inf without points."""
    if not len(pts):
        return np.full(arcs.shape[:2], np.inf)
    flat = arcs.reshape(-1, 2)
    d2 = (flat**2).sum(1)[:, None] + (pts**2).sum(1)[None, :] - 2.0 * flat @ pts.T
    return np.sqrt(np.maximum(d2.min(axis=1), 0.0)).reshape(arcs.shape[:2])
