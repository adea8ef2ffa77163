"""N robots localizing from one served map on loopback, and a new version switched to by all of them.

Per robot count N (`--robots 1 2 4`): a map service process (`MapServer` on a router-mode Zenoh
session, the store in a temporary folder, version 1 added) and N `litevloc run` processes, each in
its own namespace, replaying the same short recording with `--map zenoh:fleet` (each fetches into
its own cache and follows the map's announcements). Once every robot has published fused poses for
`--switch-after` seconds, the service publishes version 2 (a prepared second build) and announces
it; every robot fetches it and switches between two VLoc results. A Zenoh client of the bench
connected to the router subscribes to every key: payload bytes per robot namespace (steady-state
wire traffic) and the fused poses (the pose step at the switch, LOST-flagged poses). CPU of each
robot (its process and children: the VLoc process, the recording reader) and of the service come
from /proc, sampled every 0.25 s.

Input: the 7-Scenes held-out map (frames 0:500:5) as version 1, a rebuild from other frames
(2:500:5, same ground-truth frame, no node in common) as version 2, and the held-out query
recording (frames 500:1000:10: 50 frames at 3 Hz with 100 Hz odometry) replayed at `--rate` —
built here on first use (experiments/fleet_inputs.py, cached under out/bench/inputs/fleet), or
`--v1 --v2 --rec`.

    python bench/fleet.py --robots 1 2 4 --json out/bench/fleet.json [--quick]
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

from _common import INPUTS, ROOT, print_table, require_7scenes, write_json

from litevloc.experiments.fleet import (
    CONTRACT_KEYS,
    PoseTrack,
    RobotFigures,
    error_split,
    fleet_entry,
    fleet_estimate,
    keyframe_path_m,
    max_step_m,
)
from litevloc.experiments.fleet_inputs import fleet_inputs

NAME = "fleet"
LOST_VARIANCE = 1.0e4  # runtime.lost_variance: a LOST-flagged pose's covariance diagonal is at least this
JUMP_WINDOW_S = 1.0  # the pose step "at the switch": consecutive poses received within this of it


def serve(store: Path, endpoint: str, v1: Path) -> None:
    """The map service process: version 1 of `NAME` added, READY printed; each stdin line
    `publish PATH` adds PATH as the latest version and announces it (prints `ANNOUNCED WALL VERSION`);
    at EOF prints `USAGE {json}` (own CPU seconds and peak RSS) and exits."""
    from litevloc.base.process_usage import cpu_seconds, peak_rss_mb
    from litevloc.config.schema import ZenohConfig
    from litevloc.runtime.maps.server import MapServer
    from litevloc.runtime.maps.store import MapStore
    from litevloc.runtime.transport.bus import open_session

    st = MapStore(store)
    st.add_version(NAME, v1)
    session = open_session(ZenohConfig(listen=(endpoint,)), mode="router")
    server = MapServer(session, st)
    print("READY", flush=True)
    for line in sys.stdin:
        cmd, _, arg = line.strip().partition(" ")
        if cmd == "publish":
            info = server.publish(NAME, Path(arg))
            print(f"ANNOUNCED {time.time():.6f} {info.version}", flush=True)
    server.close()
    session.close()
    print("USAGE " + json.dumps({"cpu_s": cpu_seconds(), "peak_rss_mb": peak_rss_mb()}), flush=True)


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

    def close(self) -> None:
        self.sub.undeclare()
        self.session.close()


def _robot_cmd(args: argparse.Namespace, k: int, endpoint: str, port: int, tmp: Path) -> list[str]:
    return [sys.executable, "-m", "litevloc.cli.main", "run", "--config", args.config, "--source", str(args.rec),
            "--rate", str(args.rate), "--map", f"zenoh:{NAME}", "--connect", endpoint, "--namespace", f"robot{k}",
            "--listen", f"tcp/127.0.0.1:{port}", "--set", f"fleet.cache_dir={tmp / f'cache{k}'}",
            "--set", f"fleet.query_timeout_s={args.query_timeout:g}",
            *[a for o in args.overrides for a in ("--set", o)], "--json", str(tmp / f"robot{k}.json")]


def _wait_line(proc: subprocess.Popen[str], prefix: str, timeout_s: float) -> str:
    assert proc.stdout is not None
    t_end = time.monotonic() + timeout_s
    while time.monotonic() < t_end:
        line = proc.stdout.readline()
        if not line and proc.poll() is not None:
            break
        if line.startswith(prefix):
            return line.strip()
    raise SystemExit(f"map service: no {prefix} line within {timeout_s:g} s (exit code {proc.poll()})")


def _start_server(tmp: Path, v1: Path) -> tuple[subprocess.Popen[str], str]:
    """The map service in its own process on a free loopback port, `v1` served as `NAME`; READY awaited."""
    sys.path.insert(0, str(ROOT / "tests" / "runtime"))
    from zenoh_helpers import free_port

    ep = f"tcp/127.0.0.1:{free_port()}"
    server = subprocess.Popen([sys.executable, __file__, "--serve", str(tmp / "store"), ep, str(v1)],
                              stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    _wait_line(server, "READY", 120)
    return server, ep


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
        server, ep = _start_server(tmp, map_dir)
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


def one_count(args: argparse.Namespace, n: int) -> dict[str, Any]:
    """Run the fleet of `n` robots once; the contract entry (see experiments/fleet.py)."""
    from litevloc.config import load_config
    sys.path.insert(0, str(ROOT / "tests" / "runtime"))
    from zenoh_helpers import free_port

    with tempfile.TemporaryDirectory() as tmp_s:
        tmp = Path(tmp_s)
        server, ep = _start_server(tmp, args.v1)
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
        deadline = time.monotonic() + args.timeout
        while any(p.poll() is None for p in procs.values()) and time.monotonic() < deadline:
            time.sleep(0.2)
            with wire.lock:
                firsts = [wire.poses[ns].wall_s[0] if wire.poses[ns].wall_s else None for ns in names]
            if announce_wall is None and all(f is not None for f in firsts) and \
                    time.time() - max(f for f in firsts if f is not None) >= args.switch_after:
                server.stdin.write(f"publish {args.v2}\n")
                server.stdin.flush()
                announce_wall = float(_wait_line(server, "ANNOUNCED", 120).split()[1])
                print(f"  version 2 announced {announce_wall - t_start:.1f} s into the run", flush=True)
        for p in procs.values():
            if p.poll() is None:
                p.terminate()  # the recording outlasted --timeout: SIGTERM ends `run` with its status JSON
            p.wait(timeout=60)
        run_s = time.time() - t_start
        sampler.stop()
        wire.close()
        for f in logs:
            f.close()
        server.stdin.close()
        usage = json.loads(_wait_line(server, "USAGE", 60).split(" ", 1)[1])
        server.wait(timeout=30)
        robots = []
        for k, ns in enumerate(names):
            robots.append(_robot_figures(tmp, k, ns, wire, sampler, announce_wall, gt))
            if not (tmp / f"robot{k}.json").is_file():
                print((tmp / f"robot{k}.log").read_text()[-3000:], file=sys.stderr)
        server_cpu = sampler.cpu_between("server", t_start, t_start + run_s)
        entry = fleet_entry(robots, fetch_s=fetch_s, fetch_bytes=fetched.bytes_fetched, announce_wall=announce_wall,
                            server_rss_mb=max(sampler.server_rss_mb, usage["peak_rss_mb"]), server_cpu_s=server_cpu,
                            run_s=run_s)
        entry.update({"run_s": run_s, "server_cpu_s_total": usage["cpu_s"], "rate": args.rate,
                      "robot_exit_codes": [p.returncode for p in procs.values()],
                      "lost_poses_before_announce": [sum(1 for t in wire.lost_wall[ns]
                                                         if announce_wall is None or t < announce_wall)
                                                     for ns in names]})
        if args.keep_logs:
            keep = Path(args.keep_logs) / f"robots{n}"
            shutil.copytree(tmp, keep, dirs_exist_ok=True, ignore=shutil.ignore_patterns("cache*", "store", "bench_*"))
        return entry


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
        jump_m=jump, step_m=step, wire_bytes=sum(by_topic.values()), wire_bytes_by_topic=by_topic)


def _inputs(args: argparse.Namespace) -> None:
    """Default inputs: built here from the 7-Scenes data (cached under out/bench/inputs/fleet)."""
    if None in (args.v1, args.v2, args.rec):
        made = fleet_inputs(require_7scenes(), INPUTS / "fleet")
        args.v1, args.v2, args.rec = args.v1 or made.v1, args.v2 or made.v2, args.rec or made.rec


def _cm(x: float | None) -> str:
    return "-" if x is None else f"{100 * x:.1f}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--robots", type=int, nargs="+", default=[1, 2, 4])
    ap.add_argument("--v1", type=Path, default=None, help="map folder served as version 1")
    ap.add_argument("--v2", type=Path, default=None, help="map folder published mid-run as version 2")
    ap.add_argument("--rec", type=Path, default=None, help="recording each robot replays")
    ap.add_argument("--config", default="7scenes")
    ap.add_argument("--rate", type=float, default=0.5, help="replay rate (a real-time factor)")
    ap.add_argument("--switch-after", type=float, default=8.0,
                    help="publish version 2 this long after every robot's first fused pose (s)")
    ap.add_argument("--timeout", type=float, default=300.0, help="per robot count (s)")
    ap.add_argument("--query-timeout", type=float, default=30.0,
                    help="fleet.query_timeout_s of the bench's fetch and every robot (a loaded machine answers late)")
    ap.add_argument("--set", dest="overrides", action="append", default=[], help="config override for every robot")
    ap.add_argument("--quick", action="store_true", help="short run: replay rate 1, switch 4 s after the first poses")
    ap.add_argument("--keep-logs", default=None, metavar="DIR", help="keep each robot's log and status JSON here")
    ap.add_argument("--json", default="fleet", help="JSON name under out/bench, or a path ending .json")
    ap.add_argument("--large-map", type=Path, default=None, metavar="MAP",
                    help="also serve this map folder alone and time one fetch of it (e.g. the simulated office's "
                         "map, ~150 m of keyframe path: out/bench/inputs/office/map)")
    ap.add_argument("--serve", nargs=3, metavar=("STORE", "ENDPOINT", "V1"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.serve:
        serve(Path(args.serve[0]), args.serve[1], Path(args.serve[2]))
        return
    if args.quick:
        args.rate, args.switch_after = 1.0, 4.0
    _inputs(args)
    entries = []
    for n in args.robots:
        print(f"fleet of {n} robot(s) ...", flush=True)
        entries.append(one_count(args, n))
    rows = [[e["robots"], e["fetch_s"], e["fetch_bytes"], e["switch_s_max"], e["robots_switched"],
             e["lost_during_switch"], e["max_jump_m"], " ".join(f"{h:.2f}" for h in e["vloc_hz_per_robot"]),
             " ".join("-" if c is None else f"{c:.2f}" for c in e["cpu_s_per_vloc"]), e["server_rss_mb"],
             e["server_cpu_percent"], e["wire_bytes_per_robot_per_min"],
             " ".join(_cm(b) + "/" + _cm(a) for b, a in zip(e["fused_error_m_before_switch"],
                                                         e["fused_error_m_after_switch"], strict=True))]
            for e in entries]
    print_table(f"{len(entries)} fleet runs on loopback ({os.cpu_count()} CPUs), replay rate {args.rate:g}",
                ["robots", "fetch s", "fetch bytes", "switch s max", "switched", "LOST", "jump m", "VLoc Hz",
                 "CPU s/VLoc", "server RSS MB", "server CPU %", "wire B/robot/min",
                 "error cm before/after"], rows)
    missing = [k for e in entries for k in CONTRACT_KEYS if k not in e]
    assert not missing, missing
    large = None
    if args.large_map:
        large = large_map_fetch(args.large_map, args.query_timeout)
        print(f"large map: {large['keyframes']} keyframes, {large['keyframe_path_m']:.0f} m of keyframe path, "
              f"{large['fetch_bytes']} bytes in {large['chunks']} chunks fetched in {large['fetch_s']:.2f} s")
    write_json(args.json, {"runs": entries, "large_map_fetch": large, "estimate_50": fleet_estimate(entries),
                           "rate": args.rate, "config": args.config, "v1": str(args.v1), "v2": str(args.v2),
                           "rec": str(args.rec)})


if __name__ == "__main__":
    main()
