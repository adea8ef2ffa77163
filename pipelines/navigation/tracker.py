"""`SubgoalTracker`: following a node path on the map from fused robot positions.

It follows the path node by node, advancing when the robot is within `reach_m` of the current
subgoal, replanning from the nearest node when the robot strays farther than `stray_m` from the
path segment it is on (last reached node or start -> current subgoal), and reporting its
`NavState`. The nearest node comes from a KD-tree (`topomap.node_index.NodeIndex`) over the
tracker's node positions. Where the straight line to the subgoal node crosses a wall on the
occupancy grid, `NavStatus.via` is the next turn of the grid path there
(`approach.plan_approach`, `leg_detour_m`). Paths are planned on `graph.against_view_graph`.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from enum import Enum

import numpy as np
from numpy.typing import NDArray

from litevloc.base.params.navigation import TrackerParams
from litevloc.pipelines.navigation.approach import plan_approach
from litevloc.pipelines.navigation.graph import (
    NavigationError,
    against_view_graph,
    segment_clear,
    segment_distance,
    shortest_path,
)
from litevloc.pipelines.topomap.node_index import NodeIndex
from litevloc.pipelines.topomap.types import TopoMap


class NavState(str, Enum):
    """Where the tracker is with its goal (the planner service reports these values)."""

    # printed and formatted as its value, like 3.11's StrEnum (Python 3.10 has none)
    def __str__(self) -> str:
        return str(self.value)

    def __format__(self, spec: str) -> str:
        return format(str(self.value), spec)

    IDLE = "idle"  # no goal
    PLANNED = "planned"  # a path to follow
    REACHED = "reached"
    FAILED = "failed"


@dataclass(frozen=True)
class NavStatus:
    """The tracker's answer to a goal or a robot position: its state and why, the subgoal node,
    the node path left and its length (m, from the robot through the grid turns)."""

    state: NavState
    reason: str
    subgoal: int | None = None
    path: tuple[int, ...] = ()
    remaining_m: float = 0.0
    # (3,) map-frame point to drive to first: the next turn of the grid path to the subgoal node
    # where the straight line there crosses a wall; None: drive to the node
    via: tuple[float, float, float] | None = None


# nearest nodes tried for a plan's start in clear line from the robot (`SubgoalTracker.start_node`)
_START_CANDIDATES = 16


class SubgoalTracker:
    """Follow a node path on the map from fused robot positions (map frame).

    `positions` (N, 3): where the robot should be at each node (default: the keyframes'
    camera centres; the planner service passes the matching base positions)."""

    def __init__(self, topomap: TopoMap, params: TrackerParams = TrackerParams(),
                 positions: NDArray[np.floating] | None = None) -> None:
        self.map = topomap
        self.params = params
        self.positions = np.asarray(topomap.positions if positions is None else positions, np.float64)
        if self.positions.shape != (topomap.n_nodes, 3):
            raise ValueError(f"positions must be ({topomap.n_nodes}, 3), got {self.positions.shape}")
        self.index = NodeIndex(self.positions)
        self.graph = against_view_graph(topomap, params.against_view_cost, params.against_view_deg)
        self.goal: int | None = None
        self.path: list[int] = []
        self.status = NavStatus(NavState.IDLE, "no goal")
        self.replans = 0
        self._seg_start: NDArray[np.float64] | None = None  # where the current path segment starts
        self._via: list[NDArray[np.float64]] = []  # grid-path turns still to drive to before path[0]
        self._via_node: int | None = None  # the subgoal node `_via` leads to
        self._prev_node: int | None = None  # the node last passed (the start node after a plan)
        # metres of each connectivity edge: what the mapping pass drove between consecutive keyframes
        self._edge_m = {(min(i, j), max(i, j)): float(m)
                        for (i, j), m in zip(topomap.conn_edges.tolist(), topomap.conn_metres.tolist(), strict=True)}

    def nearest_node(self, position: NDArray[np.floating]) -> int:
        return self.index.nearest(np.asarray(position, np.float64)[:3])[0]

    def start_node(self, position: NDArray[np.floating]) -> int:
        """Where a plan from `position` (map frame, m) starts: the nearest of the `_START_CANDIDATES`
        nearest nodes whose straight line from the robot crosses no wall on the map's grid, else
        the nearest node. The nearest node alone can lie behind a wall: a robot that had reached
        a goal in a room 1.9 m from a corridor keyframe was planned from the corridor and sent at
        the wall."""
        p = np.asarray(position, np.float64)[:3]
        nearest = self.nearest_node(p)
        if self.map.grid.cells.size == 0 or segment_clear(self.map, p, self.positions[nearest], 0.0):
            return nearest
        k = min(_START_CANDIDATES, len(self.index))
        _, ids = self.index.tree.query(p, k=k)
        for i in np.atleast_1d(ids):
            if segment_clear(self.map, p, self.positions[int(i)], 0.0):
                return int(i)
        return nearest

    def _plan(self, position: NDArray[np.floating]) -> NavStatus:
        assert self.goal is not None
        start = self.start_node(position)
        self._seg_start = np.asarray(position, dtype=np.float64)[:3].copy()
        self._via_node = None
        self._prev_node = None
        try:
            self.path, length = shortest_path(self.map, start, self.goal, self.graph)
        except NavigationError as exc:
            self.status = NavStatus(NavState.FAILED, str(exc))
            return self.status
        self.status = NavStatus(NavState.PLANNED, f"path of {len(self.path)} nodes", self.path[0], tuple(self.path),
                                length)
        return self.status

    def set_goal(self, goal: int, position: NDArray[np.floating]) -> NavStatus:
        """Plan from the node nearest to `position` (map frame, metres) to node `goal`."""
        if not 0 <= goal < self.map.n_nodes:
            raise NavigationError(f"goal node {goal} not in the map")
        self.goal = goal
        return self._plan(position)

    def update(self, position: NDArray[np.floating]) -> NavStatus:
        """Advance/replan from a new robot position; returns the current status."""
        if self.goal is None or self.status.state is not NavState.PLANNED:
            return self.status
        p = np.asarray(position, dtype=np.float64)[:3]
        pos = self.positions
        while self.path and np.linalg.norm(pos[self.path[0]] - p) <= self.params.reach_m:
            if len(self.path) > 1 and self.params.clearance_m > 0 and \
                    np.linalg.norm(pos[self.path[0]] - p) > self.params.reach_m / 3 and \
                    not segment_clear(self.map, p, pos[self.path[1]], self.params.clearance_m):
                break  # the way on is blocked from here: get closer to this node first
            self._prev_node = self.path.pop(0)
            self._seg_start = pos[self._prev_node].copy()
        if not self.path:
            self.status = NavStatus(NavState.REACHED, f"within {self.params.reach_m} m of goal node {self.goal}")
            return self.status
        via = self._leg_via(p)
        target = pos[self.path[0]] if via is None else via
        if segment_distance(p, p if self._seg_start is None else self._seg_start, target) > self.params.stray_m:
            self.replans += 1
            return self._plan(p)
        legs = np.vstack([p, *self._via, pos[self.path]])  # (K, 3) the way on, through the grid turns
        rem = float(np.linalg.norm(np.diff(legs, axis=0), axis=1).sum())
        self.status = NavStatus(NavState.PLANNED, "following", self.path[0], tuple(self.path), rem,
                                None if via is None else (float(via[0]), float(via[1]), float(via[2])))
        return self.status

    def _leg_via(self, p: NDArray[np.float64]) -> NDArray[np.float64] | None:
        """The next turn (3,) of the grid path to the subgoal node `path[0]` from the robot at `p`
        when the straight line there crosses a wall on the map's grid, else None. Planned once per
        subgoal node (and after a replan); turns within `reach_m` are passed."""
        node = self.path[0]
        if node != self._via_node:
            leg_m = self._edge_m.get((min(node, self._prev_node), max(node, self._prev_node)), 0.0) \
                if self._prev_node is not None else 0.0
            self._via_node, self._via = node, self._grid_turns(p, self.positions[node], leg_m)
        while self._via and np.linalg.norm(self._via[0] - p) <= self.params.reach_m:
            self._seg_start = self._via.pop(0)
        return self._via[0] if self._via else None

    def _grid_turns(self, p: NDArray[np.float64], node_xyz: NDArray[np.float64],
                    leg_m: float = 0.0) -> list[NDArray[np.float64]]:
        """Turns (map frame, at the robot's height) of the grid path from `p` to a node whose
        straight line crosses an occupied cell (a wall, with the door to go out of first beside
        it: a local planner that sees only what is ahead drives into the wall); [] where the line
        is clear, the grid has no path within `leg_detour_m` more than the leg, or the option is
        off. The leg is the straight line, or `leg_m` (m) where longer: the metres the mapping pass
        drove along the edge to the node (consecutive keyframes far apart, the rooms between
        covered by other keyframes: the straight line runs through walls, and the way is the
        long one the mapping robot took). Only a line through a wall counts: a corner or a desk
        the line passes within the robot's radius the local planner steers round itself, and
        grid turns that keep just the robot's radius from it would lead it closer."""
        prm = self.params
        straight = float(np.linalg.norm(node_xyz - p))
        if prm.leg_detour_m <= 0 or straight <= prm.reach_m or \
                segment_clear(self.map, p, node_xyz, 0.0):  # also True on a map without a grid
            return []
        detour = prm.leg_detour_m + max(0.0, leg_m - straight)
        way = plan_approach(self.map.grid, p, node_xyz, replace(prm, approach_detour_m=detour))
        if way.waypoints is None:
            return []
        return [w.copy() for w in way.waypoints[:-1]]
