"""N robots localizing from one served map on loopback, and one robot's push of a changed area
switched to by all of them.

Per robot count N (`--robots 1 2 4`): a map service process (`MapServer` on a router-mode Zenoh
session, the store in a temporary folder, version 1 added, the held-out gate of
runtime/tools/map_candidates.py deciding pushes) and N `litevloc run` processes, each in its own
namespace, replaying the same recording with `--map zenoh:fleet` (each fetches into its own cache
and follows the map's announcements). Once every robot has published fused poses for
`--switch-after` seconds, robot0 pushes its mapping pass of the changed area with the real push
path (`litevloc map push REC --to fleet`, a child process): the service uploads it, builds a
candidate with `map update`, localizes its held-out recording with the current version and the
candidate, and publishes and announces the candidate only if it is not worse; every robot then
fetches it and switches between two VLoc results. A refused push is a result too (its reason is in
the JSON; no robot switches). A Zenoh client of the bench connected to the router subscribes to
every key: payload bytes per robot namespace (steady-state wire traffic) and the fused poses (the
pose step at the switch, LOST-flagged poses). CPU of each robot (its process and children: the VLoc
process, the recording reader) and of the service come from /proc, sampled every 0.25 s.

Input (experiments/fleet_inputs.py `sim_fleet_inputs`, rendered on first use and cached under
out/bench/inputs/fleet_sim, or `--v1 --rec --push --held-out`): the simulated office, version 1
mapped from the first 40 s of its mapping pass (the first room); the building after a change
(`furniture=0.3`: a cabinet of that room slid along its wall): the recording the robots replay
(every 5th camera frame kept: 3 Hz, odometry at its full 200 Hz), robot0's 10 s mapping
pass of the changed room (what it pushes), and the service's held-out recording (every
`--held-out-every`-th frame checked).

Each robot's LOST stretches are kept in recording time; `--control` runs each robot count again
without the push, so a stretch the control has too is told from one the switch caused (`--no-push`:
the control alone).

    python bench/fleet.py --robots 1 2 4 --json out/bench/fleet.json [--control] [--quick]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _common import INPUTS, ROOT, print_table, write_json

from litevloc.experiments.fleet import (
    CONTRACT_KEYS,
    PUSH_KEYS,
    PoseTrack,
    PushFigures,
    RobotFigures,
    control_entry,
    error_split,
    fleet_entry,
    fleet_estimate,
    keyframe_path_m,
    lost_spans,
    max_step_m,
    push_entry,
)
from litevloc.experiments.fleet_inputs import sim_fleet_inputs

NAME = "fleet"
LOST_VARIANCE = 1.0e4  # runtime.lost_variance: a LOST-flagged pose's covariance diagonal is at least this
JUMP_WINDOW_S = 1.0  # the pose step "at the switch": consecutive poses received within this of it


def serve(spec: dict[str, Any]) -> None:
    """The map service process. `spec`: `store` folder, `endpoint`, `v1` (added as the first version
    of `NAME`), optional `held_out` recording with `held_out_every`, `config` and `overrides` (the push gate; its
    score of version 1 is computed before READY, as a running service has it after its first push).
    Prints `READY {json}` (the gate's preparation), `ANNOUNCED WALL VERSION` per announcement,
    `VERDICT WALL {json}` per push decided; at stdin EOF `USAGE {json}` (own CPU seconds and peak
    RSS), then exits."""
    from litevloc.base.process_usage import cpu_seconds, peak_rss_mb
    from litevloc.config import load_config
    from litevloc.config.schema import ZenohConfig
    from litevloc.runtime.maps.server import MapServer
    from litevloc.runtime.maps.store import MapStore
    from litevloc.runtime.transport.bus import open_session

    st = MapStore(Path(spec["store"]))
    st.add_version(NAME, Path(spec["v1"]))
    gate, ready = None, {}
    if spec.get("held_out"):
        from litevloc.runtime.tools.map_candidates import HeldOutGate

        cfg = load_config(spec["config"], spec.get("overrides", ()))
        t0, c0 = time.perf_counter(), cpu_seconds()
        gate = HeldOutGate(cfg, Path(spec["held_out"]), frames=slice(None, None, int(spec["held_out_every"])),
                           median_tolerance_m=cfg.fleet.push_median_tolerance_m)
        score = gate.prepare(st.map_path(NAME, st.latest(NAME).version))
        ready = {"current": score.to_json(), "seconds": time.perf_counter() - t0, "cpu_s": cpu_seconds() - c0}

    def on_event(what: str, data: dict[str, Any]) -> None:
        if what == "announce":
            print(f"ANNOUNCED {time.time():.6f} {data['version']}", flush=True)
        elif what == "push":
            print(f"VERDICT {time.time():.6f} {json.dumps(data)}", flush=True)

    session = open_session(ZenohConfig(listen=(spec["endpoint"],)), mode="router")
    server = MapServer(session, st, gate=gate, on_event=on_event)
    print("READY " + json.dumps(ready), flush=True)
    for _ in sys.stdin:
        pass
    server.close()
    session.close()
    print("USAGE " + json.dumps({"cpu_s": cpu_seconds(), "peak_rss_mb": peak_rss_mb()}), flush=True)


class ServerLog:
    """The map service's stdout lines, read on a thread as they come (wall time received, line)."""

    def __init__(self, proc: subprocess.Popen[str]) -> None:
        self.proc = proc
        self.lines: list[tuple[float, str]] = []
        self._lock = threading.Lock()
        self._t = threading.Thread(target=self._run, daemon=True)
        self._t.start()

    def _run(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            with self._lock:
                self.lines.append((time.time(), line.rstrip("\n")))

    def get(self, prefix: str) -> str | None:
        """The first line that starts with `prefix` (None: none yet)."""
        with self._lock:
            return next((ln for _, ln in self.lines if ln.startswith(prefix + " ") or ln == prefix), None)

    def wait(self, prefix: str, timeout_s: float) -> str:
        t_end = time.monotonic() + timeout_s
        while time.monotonic() < t_end:
            line = self.get(prefix)
            if line is not None:
                return line
            if self.proc.poll() is not None and not self._t.is_alive():
                break
            time.sleep(0.05)
        raise SystemExit(f"map service: no {prefix} line within {timeout_s:g} s (exit code {self.proc.poll()})")


def _tree_cpu(pid: int) -> dict[int, float]:
    """CPU seconds (user + system) of `pid` and its descendants, per pid (those that have ended are absent)."""
    tick = os.sysconf("SC_CLK_TCK")
    out: dict[int, float] = {}
    todo = [pid]
    while todo:
        p = todo.pop()
        try:
            with open(f"/proc/{p}/stat") as f:
                fields = f.read().rsplit(")", 1)[1].split()
            out[p] = (int(fields[11]) + int(fields[12])) / tick
            for name in os.listdir(f"/proc/{p}/task"):
                with open(f"/proc/{p}/task/{name}/children") as f:
                    todo += [int(c) for c in f.read().split()]
        except (OSError, ValueError, IndexError):
            continue
    return out


def _rss_mb(pid: int) -> float:
    try:
        with open(f"/proc/{pid}/status") as f:
            return next(int(ln.split()[1]) for ln in f if ln.startswith("VmRSS:")) / 1024
    except (OSError, StopIteration):
        return 0.0


class Sampler:
    """Every `period_s`: each watched process tree's CPU seconds (the largest value seen per pid, so
    a child that ended still counts) and the service's RSS, as (wall time, value) samples."""

    def __init__(self, robots: dict[str, int], server: int, period_s: float = 0.25) -> None:
        self.robots, self.server = robots, server
        self._seen: dict[str, dict[int, float]] = {k: {} for k in [*robots, "server"]}
        self.cpu: dict[str, list[tuple[float, float]]] = {k: [] for k in [*robots, "server"]}
        self.server_rss_mb = 0.0
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._run, args=(period_s,), daemon=True)
        self._t.start()

    def _run(self, period_s: float) -> None:
        while not self._stop.wait(period_s):
            t = time.time()
            for k, pid in [*self.robots.items(), ("server", self.server)]:
                seen = self._seen[k]
                for p, c in _tree_cpu(pid).items():
                    seen[p] = max(seen.get(p, 0.0), c)
                self.cpu[k].append((t, sum(seen.values())))
            self.server_rss_mb = max(self.server_rss_mb, _rss_mb(self.server))

    def cpu_between(self, key: str, t0: float, t1: float) -> float:
        """CPU seconds of `key` between the samples nearest to wall times t0 and t1."""
        s = self.cpu[key]
        if not s:
            return 0.0
        near = [min(s, key=lambda x: abs(x[0] - t)) for t in (t0, t1)]
        return near[1][1] - near[0][1]

    def stop(self) -> None:
        self._stop.set()
        self._t.join()


class Wire:
    """A client of the router subscribed to every key: payload bytes per robot namespace as
    (wall time, bytes) and each robot's fused poses (position, LOST flag)."""

    def __init__(self, endpoint: str, namespaces: list[str], T_base_camera: Any) -> None:
        from litevloc.config.schema import ZenohConfig
        from litevloc.runtime.transport.bus import open_session

        self.lock = threading.Lock()
        self.bytes: dict[str, list[tuple[float, int, str]]] = {ns: [] for ns in namespaces}  # (wall, bytes, topic)
        self.poses: dict[str, PoseTrack] = {ns: PoseTrack() for ns in namespaces}
        self.lost_wall: dict[str, list[float]] = {ns: [] for ns in namespaces}
        self.lost_stamp_ns: dict[str, list[int]] = {ns: [] for ns in namespaces}  # the LOST poses' stamps
        #: (receive wall s, stamp ns, camera position in the map frame m) per fused pose
        self.cam: dict[str, list[tuple[float, int, tuple[float, float, float]]]] = {ns: [] for ns in namespaces}
        self.T_base_camera = T_base_camera
        self.session = open_session(ZenohConfig(mode="client", listen=(), connect=(endpoint,), connect_timeout_s=5.0))
        self.sub = self.session.declare_subscriber("**", self._on_sample)

    def _on_sample(self, sample: Any) -> None:
        from litevloc.hw import ros_msgs

        t = time.time()
        key = str(sample.key_expr)
        ns = key.split("/", 1)[0]
        if ns not in self.bytes:
            return
        payload = sample.payload.to_bytes()
        pose = None
        if key == f"{ns}/litevloc/pose":
            try:
                t_ns, T, cov = ros_msgs.odometry_to_matrix(ros_msgs.deserialize(payload, ros_msgs.ODOMETRY))
                cam = tuple(float(v) for v in (T @ self.T_base_camera)[:3, 3])
                pose = (tuple(float(v) for v in T[:3, 3]), cov is not None and float(cov[0, 0]) >= LOST_VARIANCE,
                        t_ns, cam)
            except ros_msgs.MessageDecodeError:
                pass
        with self.lock:
            self.bytes[ns].append((t, len(payload), key[len(ns) + 1:]))
            if pose is not None:
                self.poses[ns].add(t, pose[0])
                self.cam[ns].append((t, pose[2], pose[3]))  # type: ignore[arg-type]
                if pose[1]:
                    self.lost_wall[ns].append(t)
                    self.lost_stamp_ns[ns].append(int(pose[2]))

    def close(self) -> None:
        self.sub.undeclare()
        self.session.close()


def _robot_cmd(args: argparse.Namespace, k: int, endpoint: str, port: int, tmp: Path) -> list[str]:
    return [sys.executable, "-m", "litevloc.cli.main", "run", "--config", args.config, "--source", str(args.rec),
            "--rate", str(args.rate), "--map", f"zenoh:{NAME}", "--connect", endpoint,
            "--namespace", f"robot{k}", "--listen", f"tcp/127.0.0.1:{port}",
            "--set", f"fleet.cache_dir={tmp / f'cache{k}'}", "--set", f"fleet.query_timeout_s={args.query_timeout:g}",
            *[a for o in args.overrides for a in ("--set", o)], "--json", str(tmp / f"robot{k}.json")]


def _push_cmd(args: argparse.Namespace, endpoint: str, tmp: Path) -> list[str]:
    """robot0's push of its recording of the changed area: the `litevloc map push` a user types."""
    return [sys.executable, "-m", "litevloc.cli.main", "map", "push", str(args.push), "--to", NAME,
            "--connect", endpoint, "--config", args.config, "--set", f"fleet.query_timeout_s={args.query_timeout:g}",
            "--set", f"fleet.commit_timeout_s={args.timeout:g}", "--json", str(tmp / "push.json")]


def _start_server(tmp: Path, v1: Path, gate: dict[str, Any] | None = None
                  ) -> tuple[subprocess.Popen[str], str, ServerLog, dict[str, Any]]:
    """The map service in its own process on a free loopback port, `v1` served as `NAME`, pushes
    decided by the held-out gate `gate` (`held_out`, `held_out_every`, `config`; None: refused);
    READY awaited. (process, endpoint, its stdout, the READY line's JSON)."""
    sys.path.insert(0, str(ROOT / "tests" / "runtime"))
    from zenoh_helpers import free_port

    ep = f"tcp/127.0.0.1:{free_port()}"
    spec = {"store": str(tmp / "store"), "endpoint": ep, "v1": str(v1), **(gate or {})}
    server = subprocess.Popen([sys.executable, __file__, "--serve", json.dumps(spec)],
                              stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    out = ServerLog(server)
    ready = json.loads(out.wait("READY", 600).split(" ", 1)[1])
    return server, ep, out, ready


def _timed_fetch(ep: str, tmp: Path, timeout_s: float) -> tuple[Any, float]:
    """Fetch the latest `NAME` from the service at `ep` into an empty cache; (FetchedMap, seconds)."""
    from litevloc.config.schema import ZenohConfig
    from litevloc.runtime.maps.client import fetch_map
    from litevloc.runtime.transport.bus import open_session

    session = open_session(ZenohConfig(mode="client", listen=(), connect=(ep,), connect_timeout_s=5.0))
    try:
        t0 = time.perf_counter()
        fetched = fetch_map(session, NAME, None, tmp / "bench_cache", allow_offline=False, timeout_s=timeout_s)
        return fetched, time.perf_counter() - t0
    finally:
        session.close()


def large_map_fetch(map_dir: Path, timeout_s: float) -> dict[str, Any]:
    """Serve `map_dir` and fetch it once over loopback: bytes, chunks, seconds and the map's keyframe
    path length (metres), the issue's "fetch of a 100 m map" figure."""
    import numpy as np

    with tempfile.TemporaryDirectory() as tmp_s:
        tmp = Path(tmp_s)
        server, ep, _, _ = _start_server(tmp, map_dir)
        try:
            fetched, fetch_s = _timed_fetch(ep, tmp, timeout_s)
        finally:
            assert server.stdin is not None
            server.stdin.close()
            server.wait(timeout=60)
    nodes = map_dir / "nodes"
    return {"map": str(map_dir), "keyframes": int(np.load(nodes / "t_ns.npy").shape[0]),
            "keyframe_path_m": keyframe_path_m(np.load(nodes / "T_map_camera.npy"), np.load(nodes / "t_ns.npy")),
            "fetch_s": fetch_s, "fetch_bytes": fetched.bytes_fetched, "chunks": fetched.chunks_fetched}


def one_count(args: argparse.Namespace, n: int, push_update: bool = True) -> dict[str, Any]:
    """Run the fleet of `n` robots once, robot0 pushing unless not `push_update` (the control);
    the contract entry (see experiments/fleet.py)."""
    from litevloc.config import load_config
    sys.path.insert(0, str(ROOT / "tests" / "runtime"))
    from zenoh_helpers import free_port

    with tempfile.TemporaryDirectory() as tmp_s:
        tmp = Path(tmp_s)
        server, ep, slog, ready = _start_server(tmp, args.v1, {"held_out": str(args.held_out), "config": args.config,
                                                               "held_out_every": args.held_out_every,
                                                               "overrides": args.service_overrides})
        assert server.stdin is not None
        fetched, fetch_s = _timed_fetch(ep, tmp, args.query_timeout)
        names = [f"robot{k}" for k in range(n)]
        gt = ground_truth(args.rec)
        wire = Wire(ep, names, load_config(args.config).fusion.T_base_camera())
        logs = [open(tmp / f"robot{k}.log", "w") for k in range(n)]  # noqa: SIM115 (closed below)
        procs = {f"robot{k}": subprocess.Popen(_robot_cmd(args, k, ep, free_port(), tmp), stdout=logs[k],
                                               stderr=subprocess.STDOUT) for k in range(n)}
        sampler = Sampler({k: p.pid for k, p in procs.items()}, server.pid)
        t_start, announce_wall = time.time(), None
        push: subprocess.Popen[bytes] | None = None
        push_wall = None
        deadline = time.monotonic() + args.timeout
        while time.monotonic() < deadline:
            time.sleep(0.2)
            robots_running = any(p.poll() is None for p in procs.values())
            if push is None:
                if not robots_running:
                    break  # ended before every robot localized: no push
                with wire.lock:
                    firsts = [wire.poses[ns].wall_s[0] if wire.poses[ns].wall_s else None for ns in names]
                if all(f is not None for f in firsts) and \
                        time.time() - max(f for f in firsts if f is not None) >= args.switch_after:
                    push_wall = time.time()
                    if not push_update:  # the control: the same run without the push and its switch
                        print(f"  control run: no push ({push_wall - t_start:.1f} s into the run)", flush=True)
                        while any(p.poll() is None for p in procs.values()) and time.monotonic() < deadline:
                            time.sleep(0.2)
                        break
                    with open(tmp / "push.log", "w") as push_log:
                        push = subprocess.Popen(_push_cmd(args, ep, tmp), stdout=push_log, stderr=subprocess.STDOUT)
                    print(f"  robot0 pushes {args.push.name} {push_wall - t_start:.1f} s into the run", flush=True)
                continue
            if announce_wall is None and (line := slog.get("ANNOUNCED")) is not None:
                assert push_wall is not None  # set with the push
                announce_wall = float(line.split()[1])
                print(f"  pushed version announced {announce_wall - push_wall:.1f} s after the push began",
                      flush=True)
            if not robots_running and push.poll() is not None:
                break
        for p in procs.values():
            if p.poll() is None:
                p.terminate()  # the recording outlasted --timeout: SIGTERM ends `run` with its status JSON
            p.wait(timeout=60)
        run_s = time.time() - t_start
        if push is not None and push.poll() is None:
            push.terminate()  # no verdict within --timeout
            push.wait(timeout=30)
        sampler.stop()
        wire.close()
        for f in logs:
            f.close()
        server.stdin.close()
        usage = json.loads(slog.wait("USAGE", 60).split(" ", 1)[1])
        server.wait(timeout=30)
        robots = []
        for k, ns in enumerate(names):
            robots.append(_robot_figures(tmp, k, ns, wire, sampler, announce_wall, gt))
            if not (tmp / f"robot{k}.json").is_file():
                print((tmp / f"robot{k}.log").read_text()[-3000:], file=sys.stderr)
        steady_end = push_wall if push_wall is not None else t_start + run_s  # the service's steady state
        entry = fleet_entry(robots, fetch_s=fetch_s, fetch_bytes=fetched.bytes_fetched, announce_wall=announce_wall,
                            server_rss_mb=max(sampler.server_rss_mb, usage["peak_rss_mb"]),
                            server_cpu_s=sampler.cpu_between("server", t_start, steady_end),
                            run_s=steady_end - t_start)
        entry.update(push_entry(_push_figures(args, push, push_wall, slog, announce_wall, tmp),
                                [r.switch_wall for r in robots],
                                no_push=None if push_update else "control run: no push"))
        entry["control"] = not push_update
        wire_min = entry["wire_bytes_per_robot_per_min"]
        entry.update({"run_s": run_s, "server_cpu_s_total": usage["cpu_s"], "rate": args.rate,
                      # per minute of a robot running in real time: the fused pose (most of the bytes) goes
                      # out per odometry message, so at the replay rate's pace; status is on the wall clock,
                      # so this overstates it a little
                      "wire_bytes_per_robot_per_min_real_time": None if wire_min is None or not args.rate else
                      wire_min / args.rate,
                      "server_cpu_s_push": None if push_wall is None else
                      sampler.cpu_between("server", push_wall, t_start + run_s),
                      "gate_current_version": ready,
                      "robot_exit_codes": [p.returncode for p in procs.values()],
                      "lost_poses_before_announce": [sum(1 for t in wire.lost_wall[ns]
                                                         if announce_wall is None or t < announce_wall)
                                                     for ns in names]})
        if push is not None and push.returncode not in (0, 1):
            print((tmp / "push.log").read_text()[-3000:], file=sys.stderr)
        if args.keep_logs:
            keep = Path(args.keep_logs) / f"robots{n}"
            shutil.copytree(tmp, keep, dirs_exist_ok=True, ignore=shutil.ignore_patterns("cache*", "store", "bench_*"))
        return entry


def _push_figures(args: argparse.Namespace, push: subprocess.Popen[bytes] | None, push_wall: float | None,
                  slog: ServerLog, announce_wall: float | None, tmp: Path) -> PushFigures | None:
    """What the bench saw of robot0's push: the service's VERDICT line (else `map push`'s JSON)."""
    if push is None or push_wall is None:
        return None
    line = slog.get("VERDICT")
    verdict: dict[str, Any] = json.loads(line.split(" ", 2)[2]) if line else {}
    if not verdict and (tmp / "push.json").is_file():
        verdict = json.loads((tmp / "push.json").read_text())
    reason = verdict.get("reason")
    if not verdict:
        tail = (tmp / "push.log").read_text().strip().splitlines()[-1:] if (tmp / "push.log").is_file() else []
        reason = f"no verdict (map push exit code {push.returncode}): {' '.join(tail)}"
    return PushFigures(start_wall=push_wall, verdict_wall=float(line.split()[1]) if line else None,
                       published=verdict.get("published"), reason=reason, announce_wall=announce_wall,
                       exit_code=push.returncode, bytes=args.push.stat().st_size,
                       details=dict(verdict.get("details") or {}))


def ground_truth(rec: Path) -> dict[int, tuple[float, float, float]]:
    """The recording's ground-truth camera positions (metres, world = map frame) per stamp (ns)."""
    from litevloc.hw.messages import GroundTruthPose
    from litevloc.hw.streams.mcap_io import McapSource

    return {m.t_ns: tuple(float(v) for v in m.T_world_camera[:3, 3])  # type: ignore[misc]
            for m in McapSource(rec).messages(defer_color=True) if isinstance(m, GroundTruthPose)}


def _robot_figures(tmp: Path, k: int, ns: str, wire: Wire, sampler: Sampler, announce_wall: float | None,
                   gt: dict[int, tuple[float, float, float]]) -> RobotFigures:
    js = tmp / f"robot{k}.json"
    status = json.loads(js.read_text())["status"] if js.is_file() else {}
    track = wire.poses[ns]
    t0, t1 = (track.wall_s[0], track.wall_s[-1]) if track.wall_s else (0.0, 0.0)
    switch = (status.get("map") or {}).get("last_switch_wall")
    jump = step = None
    if switch is not None:
        jump = max_step_m(track, switch - JUMP_WINDOW_S, switch + JUMP_WINDOW_S)
        step = max_step_m(track, t0, switch - JUMP_WINDOW_S)
    in_window = [t for t in wire.bytes[ns] if t0 <= t[0] <= t1]
    by_topic: dict[str, int] = {}
    for _, b, topic in in_window:
        by_topic[topic] = by_topic.get(topic, 0) + b
    err = error_split(wire.cam[ns], gt, switch)
    return RobotFigures(
        error_before_m=err.before_m, error_after_m=err.after_m,
        vloc_calls=int(status.get("counters", {}).get("vloc_calls", 0)), stream_s=t1 - t0,
        cpu_s=sampler.cpu_between(ns, t0, t1), switch_wall=switch,
        lost=sum(1 for t in wire.lost_wall[ns] if announce_wall is not None and t >= announce_wall),
        first_lost_after_switch_s=None if switch is None else
        next((t - switch for t in wire.lost_wall[ns] if t >= switch), None),
        streamed_after_switch_s=None if switch is None else t1 - switch,
        lost_spans_s=lost_spans(wire.lost_stamp_ns[ns], min(gt, default=0)),
        jump_m=jump, step_m=step, wire_bytes=sum(by_topic.values()), wire_bytes_by_topic=by_topic)


def _inputs(args: argparse.Namespace) -> None:
    """Default inputs: the simulated office's (rendered here on first use, cached under
    out/bench/inputs/fleet_sim)."""
    if None in (args.v1, args.rec, args.push, args.held_out):
        made = sim_fleet_inputs(INPUTS / "fleet_sim")
        args.v1, args.rec = args.v1 or made.v1, args.rec or made.rec
        args.push, args.held_out = args.push or made.push, args.held_out or made.held_out


def _cm(x: float | None) -> str:
    return "-" if x is None else f"{100 * x:.1f}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--robots", type=int, nargs="+", default=[1, 2, 4])
    ap.add_argument("--v1", type=Path, default=None, help="map folder served as version 1")
    ap.add_argument("--rec", type=Path, default=None, help="recording each robot replays")
    ap.add_argument("--push", type=Path, default=None, help="recording robot0 pushes (`map push REC --to fleet`)")
    ap.add_argument("--held-out", type=Path, default=None, help="posed recording of the service's held-out gate")
    ap.add_argument("--held-out-every", type=int, default=60,
                    help="the gate localizes every N-th frame of --held-out (600 frames: 10 at the default)")
    ap.add_argument("--config", default="default")
    ap.add_argument("--rate", type=float, default=0.2,
                    help="replay rate (a real-time factor; slow enough that the push's candidate build, on the same "
                         "CPUs as the robots, ends within the robots' run)")
    ap.add_argument("--switch-after", type=float, default=4.0,
                    help="robot0 pushes this long after every robot's first fused pose (s)")
    ap.add_argument("--no-push", action="store_true",
                    help="control run: the same robots and recording without robot0's push (its LOST stretches against "
                         "a run with the push tell LOST caused by the switch from LOST where the map does not cover)")
    ap.add_argument("--control", action="store_true",
                    help="after each robot count's run, its control without the push; the entry gains the control's "
                         "LOST stretches and the run's stretches the control does not have")
    ap.add_argument("--timeout", type=float, default=300.0, help="per robot count (s)")
    ap.add_argument("--query-timeout", type=float, default=30.0,
                    help="fleet.query_timeout_s of the bench's fetch and every robot (a loaded machine answers late)")
    ap.add_argument("--set", dest="overrides", action="append", default=[], help="config override for every robot")
    ap.add_argument("--service-set", dest="service_overrides", action="append", default=[], metavar="KEY=VALUE",
                    help="config override of the map service's push gate (its map update and held-out check)")
    ap.add_argument("--quick", action="store_true",
                    help="short run: replay rate 1, push 2 s after the first poses, the gate on every 120th "
                         "held-out frame")
    ap.add_argument("--keep-logs", default=None, metavar="DIR", help="keep each robot's log and status JSON here")
    ap.add_argument("--json", default="fleet", help="JSON name under out/bench, or a path ending .json")
    ap.add_argument("--large-map", type=Path, default=None, metavar="MAP",
                    help="also serve this map folder alone and time one fetch of it (e.g. the simulated office's "
                         "map, ~150 m of keyframe path: out/bench/inputs/office/map)")
    ap.add_argument("--serve", metavar="SPEC_JSON", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.serve:
        serve(json.loads(args.serve))
        return
    if args.quick:
        args.rate, args.switch_after, args.held_out_every = 1.0, 2.0, 120
    _inputs(args)
    entries = []
    for n in args.robots:
        print(f"fleet of {n} robot(s) ...", flush=True)
        entry = one_count(args, n, push_update=not args.no_push)
        if args.control and not args.no_push:
            print(f"fleet of {n} robot(s), the control without the push ...", flush=True)
            entry.update(control_entry(entry, one_count(args, n, push_update=False)))
        entries.append(entry)
    rows = [[e["robots"], e["fetch_s"], e["fetch_bytes"], e["push_s"], e["push_to_all_switched_s"],
             "published" if e["push_published"] else "refused" if e["push_published"] is False else "-",
             e["switch_s_max"], e["robots_switched"],
             e["lost_during_switch"], e["max_jump_m"], " ".join(f"{h:.2f}" for h in e["vloc_hz_per_robot"]),
             " ".join("-" if c is None else f"{c:.2f}" for c in e["cpu_s_per_vloc"]), e["server_rss_mb"],
             e["server_cpu_percent"], e["wire_bytes_per_robot_per_min"],
             " ".join(_cm(b) + "/" + _cm(a) for b, a in zip(e["fused_error_m_before_switch"],
                                                         e["fused_error_m_after_switch"], strict=True))]
            for e in entries]
    print_table(f"{len(entries)} fleet runs on loopback ({os.cpu_count()} CPUs), replay rate {args.rate:g}",
                ["robots", "fetch s", "fetch bytes", "push s", "push->all switched s", "verdict", "switch s max",
                 "switched", "LOST", "jump m", "VLoc Hz",
                 "CPU s/VLoc", "server RSS MB", "server CPU %", "wire B/robot/min",
                 "error cm before/after"], rows)
    for e in entries:
        print(f"  {e['robots']} robot(s), robot0's push: {e['push_reason']}")
        for k, spans in enumerate(e["lost_spans_s_per_robot"]):
            text = ", ".join(f"{a:.1f}-{b:.1f}" for a, b in spans) or "never"
            print(f"    robot{k} LOST over recording s: {text}")
        for k, spans in enumerate(e.get("lost_spans_not_in_control_per_robot") or []):
            text = ", ".join(f"{a:.1f}-{b:.1f}" for a, b in spans) or "none"
            print(f"    robot{k} LOST stretches the control does not have: {text}")
    missing = [k for e in entries for k in (*CONTRACT_KEYS, *PUSH_KEYS) if k not in e]
    assert not missing, missing
    large = None
    if args.large_map:
        large = large_map_fetch(args.large_map, args.query_timeout)
        print(f"large map: {large['keyframes']} keyframes, {large['keyframe_path_m']:.0f} m of keyframe path, "
              f"{large['fetch_bytes']} bytes in {large['chunks']} chunks fetched in {large['fetch_s']:.2f} s")
    write_json(args.json, {"runs": entries, "large_map_fetch": large, "estimate_50": fleet_estimate(entries),
                           "rate": args.rate, "config": args.config, "service_overrides": args.service_overrides,
                           "v1": str(args.v1), "rec": str(args.rec),
                           "push": str(args.push), "held_out": str(args.held_out),
                           "held_out_every": args.held_out_every})


if __name__ == "__main__":
    main()
