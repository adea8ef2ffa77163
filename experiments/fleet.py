"""Figures of the fleet benchmark (bench/fleet.py): what one robot process measured, turned into the
benchmark's per-robot-count JSON entry, and the paper estimate for a larger fleet.

Kept apart from the orchestration (processes, Zenoh) so the contract is tested on recorded figures.
Times are wall-clock seconds (`time.time()`, one machine: the robots, the map service and the bench
share the clock), positions metres in the map frame.
"""

from __future__ import annotations

import bisect
import itertools
import math
import statistics
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

#: the keys every per-robot-count entry carries (issue 77, item 5)
CONTRACT_KEYS = ("robots", "fetch_s", "fetch_bytes", "switch_s_max", "lost_during_switch", "max_jump_m",
                 "vloc_hz_per_robot", "cpu_s_per_vloc", "server_rss_mb", "wire_bytes_per_robot_per_min")
#: and the pushed version's (the switch comes from one robot's `map push`)
PUSH_KEYS = ("push_s", "push_verdict_s", "push_to_all_switched_s", "push_published", "push_reason")


@dataclass
class PoseTrack:
    """Fused poses of one robot as the bench received them: receive wall time (s) and position
    (metres, map frame), in arrival order."""

    wall_s: list[float] = field(default_factory=list)
    xyz: list[tuple[float, float, float]] = field(default_factory=list)

    def add(self, wall_s: float, xyz: tuple[float, float, float]) -> None:
        self.wall_s.append(wall_s)
        self.xyz.append(xyz)


def max_step_m(track: PoseTrack, t0: float, t1: float) -> float | None:
    """The largest distance between two consecutive fused poses received in [t0, t1] (metres);
    None when fewer than two fall in the window."""
    pts = [p for t, p in zip(track.wall_s, track.xyz, strict=True) if t0 <= t <= t1]
    if len(pts) < 2:
        return None
    return max(math.dist(a, b) for a, b in itertools.pairwise(pts))


@dataclass(frozen=True)
class RobotFigures:
    """What one robot process measured over its run.

    `stream_s`: first to last fused pose received (the part of the run that localizes);
    `cpu_s`: the process and its children's CPU seconds over that span; `vloc_calls`: VLoc
    results in the run (status counter); `switch_wall`: `time.time()` of its map switch (None: it
    did not switch); `lost`: LOST entries between the announcement and the end of the run;
    `jump_m`: largest consecutive fused-pose step within the jump window around the switch;
    `step_m`: the same away from the switch (the motion between two poses, for scale);
    `wire_bytes`: payload bytes of its publications received by the bench over `stream_s`
    (`wire_bytes_by_topic`: the same per key after the namespace); `error_before_m` /
    `error_after_m`: median fused camera position error against ground truth before and after its
    switch (see `error_split`; None without ground truth or a switch); `first_lost_after_switch_s`:
    its switch to the first LOST pose after it (None: none, or no switch), `streamed_after_switch_s`:
    its switch to its last fused pose (how long the run went on on the new version); `lost_spans_s`:
    the stretches of the recording (seconds from its start, `lost_spans`) in which its fused poses were
    LOST, over the whole run: where a control run without a push (`bench/fleet.py --no-push`) has the
    same spans, the switch did not cause them."""

    vloc_calls: int
    stream_s: float
    cpu_s: float
    switch_wall: float | None
    lost: int
    jump_m: float | None
    step_m: float | None
    wire_bytes: int
    wire_bytes_by_topic: dict[str, int] = field(default_factory=dict)
    error_before_m: float | None = None
    error_after_m: float | None = None
    first_lost_after_switch_s: float | None = None
    streamed_after_switch_s: float | None = None
    lost_spans_s: list[tuple[float, float]] = field(default_factory=list)


def _finite_or_none(x: float | None) -> float | None:
    return None if x is None or not math.isfinite(x) else float(x)


def fleet_entry(robots: Sequence[RobotFigures], *, fetch_s: float, fetch_bytes: int, announce_wall: float | None,
                server_rss_mb: float, server_cpu_s: float, run_s: float) -> dict[str, Any]:
    """The benchmark's JSON object for one robot count (`CONTRACT_KEYS` plus detail).

    `switch_s_max` is the announcement to the last robot switched; None when no version was announced
    or a robot did not switch (then `robots_switched` < `robots` says how many did). `server_cpu_s`
    over `run_s` seconds of the robots' run gives `server_cpu_percent`."""
    switched = [r.switch_wall for r in robots if r.switch_wall is not None]
    all_switched = announce_wall is not None and len(switched) == len(robots) and bool(robots)
    jumps = [r.jump_m for r in robots if r.jump_m is not None]
    wire = [60.0 * r.wire_bytes / r.stream_s for r in robots if r.stream_s > 0]
    return {
        "robots": len(robots),
        "fetch_s": float(fetch_s),
        "fetch_bytes": int(fetch_bytes),
        "switch_s_max": max(switched) - announce_wall if all_switched and announce_wall is not None else None,
        "switch_s_per_robot": [None if r.switch_wall is None or announce_wall is None else r.switch_wall - announce_wall
                               for r in robots],
        "robots_switched": len(switched),
        "lost_during_switch": sum(r.lost for r in robots),
        "lost_after_announce_per_robot": [r.lost for r in robots],
        "first_lost_after_switch_s": [r.first_lost_after_switch_s for r in robots],
        "streamed_after_switch_s": [r.streamed_after_switch_s for r in robots],
        "max_jump_m": max(jumps) if jumps else None,
        "step_m_per_robot": [r.step_m for r in robots],
        "vloc_hz_per_robot": [r.vloc_calls / r.stream_s if r.stream_s > 0 else 0.0 for r in robots],
        "cpu_s_per_vloc": [_finite_or_none(r.cpu_s / r.vloc_calls) if r.vloc_calls else None for r in robots],
        "server_rss_mb": float(server_rss_mb),
        "server_cpu_percent": 100.0 * server_cpu_s / run_s if run_s > 0 else None,
        "wire_bytes_per_robot_per_min": sum(wire) / len(wire) if wire else None,
        "wire_bytes_per_min_per_robot": wire,
        "wire_bytes_per_min_by_topic": _per_min_by_topic(robots),
        "fused_error_m_before_switch": [r.error_before_m for r in robots],
        "fused_error_m_after_switch": [r.error_after_m for r in robots],
        "lost_spans_s_per_robot": [[list(span) for span in r.lost_spans_s] for r in robots],
    }


def spans_not_in(spans: Sequence[Sequence[float]], control: Sequence[Sequence[float]],
                 tolerance_s: float = 1.0) -> list[tuple[float, float]]:
    """The `spans` ((first s, last s) of recording time) that overlap none of `control`'s, each of
    those widened by `tolerance_s` on both sides (a robot's VLoc fixes land a frame earlier or later
    from run to run)."""
    return [(float(a), float(b)) for a, b in spans
            if not any(a <= d + tolerance_s and b >= c - tolerance_s for c, d in control)]


def control_entry(run: dict[str, Any], control: dict[str, Any]) -> dict[str, Any]:
    """What a run with the push adds from its control (the same robot count without the push):
    the control's LOST stretches per robot and, per robot, the run's stretches the control does not
    have (`spans_not_in`): LOST the push or the switch caused."""
    ctrl = control["lost_spans_s_per_robot"]
    return {"control_lost_spans_s_per_robot": ctrl,
            "lost_spans_not_in_control_per_robot": [
                [list(sp) for sp in spans_not_in(spans, c)]
                for spans, c in zip(run["lost_spans_s_per_robot"], ctrl, strict=True)]}


def lost_spans(stamps_ns: Sequence[int], start_ns: int, gap_s: float = 1.0) -> list[tuple[float, float]]:
    """Stretches of recording time covered by LOST poses: `stamps_ns` (the LOST poses' stamps, ns,
    any order) as seconds from `start_ns`, joined where consecutive stamps lie at most `gap_s`
    apart; [(first s, last s)], earliest first."""
    spans: list[tuple[float, float]] = []
    for t in sorted((int(x) - int(start_ns)) * 1e-9 for x in stamps_ns):
        if spans and t - spans[-1][1] <= gap_s:
            spans[-1] = (spans[-1][0], t)
        else:
            spans.append((t, t))
    return spans


@dataclass(frozen=True)
class PushFigures:
    """One robot's `litevloc map push` as the bench saw it (wall-clock seconds, one machine).

    `start_wall`: the push command started; `verdict_wall`: the map service decided (None: no
    verdict, e.g. the push did not finish); `published` / `reason` / `details`: the service's
    verdict (the held-out gate's figures in `details`); `announce_wall`: the pushed version's
    announcement (None when refused); `exit_code`: of `map push` (0 published, 1 refused, None
    still running when the bench gave up); `bytes`: the pushed recording's size."""

    start_wall: float
    verdict_wall: float | None
    published: bool | None
    reason: str | None
    announce_wall: float | None
    exit_code: int | None
    bytes: int
    details: dict[str, Any] = field(default_factory=dict)


def push_entry(push: PushFigures | None, switch_walls: Sequence[float | None],
               no_push: str | None = None) -> dict[str, Any]:
    """The push's part of a robot-count entry: `push_s` (push start to the new version published
    and announced; None when refused or undecided), `push_verdict_s` (push start to the verdict,
    either way), `push_to_all_switched_s` (push start to the last robot's switch; None unless every
    robot switched after the announcement), and the verdict (`push_published`, `push_reason`,
    `push_details`); `push` None: no push was made (every key None but the reason: `no_push`, else
    the robots ended before the push was due)."""
    if push is None:
        return {"push_s": None, "push_verdict_s": None, "push_to_all_switched_s": None, "push_published": None,
                "push_reason": no_push or "no push: the robots ended before every one had published fused poses",
                "push_details": {}, "push_exit_code": None, "push_bytes": None}
    ann = push.announce_wall if push.published else None
    all_switched = ann is not None and bool(switch_walls) and all(w is not None and w >= ann for w in switch_walls)
    return {
        "push_s": None if ann is None else ann - push.start_wall,
        "push_verdict_s": None if push.verdict_wall is None else push.verdict_wall - push.start_wall,
        "push_to_all_switched_s": max(w for w in switch_walls if w is not None) - push.start_wall
        if all_switched else None,
        "push_published": push.published,
        "push_reason": push.reason,
        "push_details": push.details,
        "push_exit_code": push.exit_code,
        "push_bytes": push.bytes,
    }


@dataclass(frozen=True)
class ErrorSplit:
    """Median fused position error (metres) of the poses received before and after a wall time,
    and how many poses each median is over."""

    before_m: float | None
    after_m: float | None
    n_before: int
    n_after: int


def error_split(poses: Sequence[tuple[float, int, tuple[float, float, float]]],
                gt: dict[int, tuple[float, float, float]], split_wall: float | None,
                max_dt_ns: int = 20_000_000) -> ErrorSplit:
    """Fused camera positions against ground truth, split at `split_wall` (a robot's map switch).

    `poses`: (receive wall time s, stamp ns, camera position in the map frame, metres), one per
    fused pose; `gt`: ground-truth camera position per stamp (ns; the map frame is the ground
    truth's world frame, as for a map posed by ground truth). Each ground-truth stamp is matched to
    the fused pose stamped nearest to it within `max_dt_ns` (fused poses come at the odometry rate,
    ground truth at the frame rate); `split_wall` None puts every pose before."""
    if not poses or not gt:
        return ErrorSplit(None, None, 0, 0)
    stamps = sorted(gt)
    order = sorted(range(len(poses)), key=lambda i: poses[i][1])
    t_sorted = [poses[i][1] for i in order]
    before: list[float] = []
    after: list[float] = []
    for t in stamps:
        k = bisect.bisect_left(t_sorted, t)
        near = [j for j in (k - 1, k) if 0 <= j < len(t_sorted)]
        j = min(near, key=lambda j: abs(t_sorted[j] - t))
        if abs(t_sorted[j] - t) > max_dt_ns:
            continue
        wall, _, xyz = poses[order[j]]
        err = math.dist(xyz, gt[t])
        (after if split_wall is not None and wall >= split_wall else before).append(err)
    return ErrorSplit(statistics.median(before) if before else None, statistics.median(after) if after else None,
                      len(before), len(after))


def _per_min_by_topic(robots: Sequence[RobotFigures]) -> dict[str, float]:
    """Mean over robots of each topic's payload bytes per minute (topic: the key after the namespace)."""
    out: dict[str, float] = {}
    timed = [r for r in robots if r.stream_s > 0]
    for r in timed:
        for topic, b in r.wire_bytes_by_topic.items():
            out[topic] = out.get(topic, 0.0) + 60.0 * b / r.stream_s / len(timed)
    return dict(sorted(out.items(), key=lambda kv: -kv[1]))


def fleet_estimate(entries: Sequence[dict[str, Any]], robots: int = 50) -> dict[str, Any]:
    """Paper figures for `robots` robots on one router and one map service, scaled linearly from the
    measured entries (the largest robot count for the per-robot figures): steady-state traffic
    through the router (per robot at real time where the entry has
    `wire_bytes_per_robot_per_min_real_time`), the server's CPU share, its RSS (the growth per robot
    between the smallest and the largest run, extended), and a fetch of every robot at once at the
    measured loopback rate (an upper bound of the wire's share: a LAN is slower)."""
    first, entry = min(entries, key=lambda e: e["robots"]), max(entries, key=lambda e: e["robots"])
    n = max(int(entry["robots"]), 1)
    # a replay slower than real time sends its poses slower: the real-time figure where the run has it
    wire = entry.get("wire_bytes_per_robot_per_min_real_time") or entry.get("wire_bytes_per_robot_per_min") or 0.0
    cpu = entry.get("server_cpu_percent")
    rate = entry["fetch_bytes"] / entry["fetch_s"] if entry.get("fetch_s") else None
    span = entry["robots"] - first["robots"]
    rss_per_robot = (entry["server_rss_mb"] - first["server_rss_mb"]) / span if span else None
    return {
        "robots": robots,
        "router_bytes_per_s": robots * wire / 60.0,
        "router_mbit_per_s": robots * wire * 8 / 60.0 / 1e6,
        "server_cpu_percent": None if cpu is None else cpu / n * robots,
        "server_rss_mb_per_robot": rss_per_robot,
        "server_rss_mb": None if rss_per_robot is None else entry["server_rss_mb"] + rss_per_robot * (robots - n),
        "all_fetch_s_at_measured_rate": None if rate is None else robots * entry["fetch_bytes"] / rate,
        "scaled_from_robots": n,
    }


def keyframe_path_m(T_map_camera: np.ndarray, t_ns: np.ndarray) -> float:
    """Length of the path through a map's keyframes in time order (metres): a lower bound of the
    mapping trajectory it was built from. `T_map_camera` (N, 4, 4), `t_ns` (N,) nanoseconds."""
    positions = T_map_camera[np.argsort(t_ns), :3, 3]
    return float(np.linalg.norm(np.diff(positions, axis=0), axis=1).sum())
