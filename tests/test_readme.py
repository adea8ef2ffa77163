"""Every usage line the README shows runs, through the installed `litevloc` console script.

The README's bash blocks are read; each `litevloc ...` line runs as written, in a scratch
folder standing in for the project root (so `out/` is scratch), with `$D` the 7-Scenes folder.
What a line needs and does not make itself is put in place first:

* `out/7s/map` and `out/7s/query.mcap` are the suite's cached held-out inputs
  (`seven_scenes_held_out`, tests/conftest.py): they were made by running exactly the README's
  two lines that make them, which this test checks;
* the robot lines run where there is no robot: `out/robot/run.mcap` is the held-out query pass
  without its ground truth (what `litevloc record` writes), so `map build` poses it with its own
  SLAM and the robot lines after it use that map; `goal.jpg` is a query frame, the Zenoh ports
  7447 (the robot's service: a Zenoh peer of this test stands in) and 7448 (the planner) free
  ports; the planner runs in the background until the goal line has been answered, then gets
  SIGINT; the camera lines must fail as the README says they do, naming the missing device.

`make` lines are CI's own (`make test` runs this). A line this test does not know fails it.
"""

from __future__ import annotations

import json
import os
import re
import shlex
import shutil
import signal
import subprocess
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from litevloc.experiments.slam import without_ground_truth
from tests.conftest import HELD_OUT_MAP_ARGS, HELD_OUT_QUERY_ARGS, HeldOut, litevloc_exe

from .runtime.zenoh_helpers import free_port

README = Path(__file__).resolve().parents[1] / "README.md"

pytestmark = [pytest.mark.shared_data, pytest.mark.slow]


def readme_commands(text: str) -> list[str]:
    """The `litevloc` lines of the README's bash blocks (comments dropped, `$D` kept)."""
    out, block = [], False
    for line in text.splitlines():
        if line.startswith("```"):
            block = line.strip() == "```bash"
            continue
        if block and line.startswith("litevloc "):
            out.append(line.split("  #")[0].strip())
    return out


def test_the_readme_parser_finds_the_usage_lines() -> None:
    text = "```bash\nmake demo   # x\nlitevloc a b  # c\n```\nlitevloc prose\n```text\nlitevloc no\n```\n"
    assert readme_commands(text) == ["litevloc a b"]


def _run(line: str, cwd: Path, env: dict[str, str], timeout: float = 300) -> subprocess.CompletedProcess[str]:
    argv = shlex.split(line)
    return subprocess.run([litevloc_exe(), *argv[1:]], cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=timeout)


def _ok(r: subprocess.CompletedProcess[str]) -> None:
    assert r.returncode == 0, (r.args, r.stdout[-2000:], r.stderr[-3000:])


def _same_recipe(line: str, args: tuple[str, ...]) -> bool:
    words = [w.replace("out/7s", "$OUT") for w in shlex.split(line)[1:]]
    return words == list(args)


@pytest.mark.timeout(900)  # every README command in turn, the one-minute demo included
def test_every_readme_usage_line_runs(seven_scenes_held_out: HeldOut, tmp_path: Path) -> None:
    lines = readme_commands(README.read_text())
    assert len(lines) >= 8, lines
    held = seven_scenes_held_out
    (tmp_path / "out" / "7s").mkdir(parents=True)
    (tmp_path / "out" / "robot").mkdir(parents=True)
    robot_port, planner_port = free_port(), free_port()
    env = {**os.environ, "D": str(held.data)}
    goal = tmp_path / "goal.jpg"
    shutil.copy(held.data / "frame-000700.color.jpg", goal)
    without_ground_truth(held.queries, tmp_path / "out" / "robot" / "run.mcap")
    planner: list[subprocess.Popen[str]] = []
    robot: list[object] = []

    def expand(line: str) -> str:
        line = line.replace("$D", str(held.data))
        return line.replace(":7447", f":{robot_port}").replace(":7448", f":{planner_port}")

    def prepared_by_fixture(line: str) -> None:
        made = {HELD_OUT_MAP_ARGS: held.map_dir, HELD_OUT_QUERY_ARGS: held.queries}
        same = [a for a in made if _same_recipe(line, a)]
        assert same, f"{line!r} is not the command that made the suite's held-out inputs {list(made)}"
        os.symlink(made[same[0]], tmp_path / "out" / "7s" / made[same[0]].name)

    def demo(line: str) -> None:
        _ok(_run(line, tmp_path, env, timeout=600))
        res = json.loads((tmp_path / "out" / "quick" / "demo.json").read_text())
        assert res["ok"] and res["navigation"]["goals_reached"] == res["navigation"]["goals_total"] == 1
        assert (tmp_path / "out" / "quick" / "demo.png").read_bytes()[:4] == b"\x89PNG"

    def map_info(line: str) -> None:
        r = _run(expand(line), tmp_path, env)
        _ok(r)
        assert "keyframes" in r.stdout or "nodes" in r.stdout, r.stdout

    def localize(line: str) -> None:
        """Held-out queries (frames 500-999) in the map of the mapping pass: most localize, and
        an accepted pose is never far off."""
        _ok(_run(expand(line), tmp_path, env))
        res = json.loads((tmp_path / "out" / "7s" / "vloc.json").read_text())
        assert res["queries"] == 10 and res["accepted"] >= 6, res
        assert res["errors"]["max_m"] < 0.25 and res["errors"]["within_25cm_5deg"] == 1.0, res["errors"]
        rows = np.loadtxt(tmp_path / "out" / "7s" / "vloc.txt").reshape(-1, 8)
        assert len(rows) == res["accepted"]

    def replay(line: str) -> None:
        """The onboard service on the first 20 frames only (`--frames`): fused poses up to the
        20th frame's stamp, none after it. Run in lockstep (`runtime.mode=deterministic`): in real
        time, a busy neighbour test can delay VLoc past these 20 frames (6.6 s of sensor time),
        and then fusion rightly never starts; the real-time path has its own tests."""
        from litevloc.hw.messages import RgbdFrame
        from litevloc.hw.streams.mcap_io import McapSource

        r = _run(expand(line) + " --set runtime.mode=deterministic", tmp_path, env)
        _ok(r)
        t = np.loadtxt(tmp_path / "out" / "7s" / "fused.txt").reshape(-1, 8)[:, 0]
        stamps = [m.t_ns * 1e-9 for m in McapSource(held.queries) if isinstance(m, RgbdFrame)]
        assert len(t) > 50 and stamps[0] - 0.5 <= t.min() and t.max() <= stamps[19] + 0.5, (t.min(), t.max())
        assert "camera ATE" in r.stdout, r.stdout

    def robot_map(line: str) -> None:
        """The robot's recording (no ground truth) becomes a map posed by its own SLAM."""
        r = _run(expand(line), tmp_path, env)
        _ok(r)
        build = json.loads((tmp_path / "out" / "robot" / "build.json").read_text())
        assert build["poses"] == "slam" and build["nodes"] >= 3, build
        assert "SLAM:" in r.stdout and "loops:" in r.stdout, r.stdout

    def no_camera(line: str) -> None:
        t0 = time.monotonic()
        r = _run(expand(line), tmp_path, env, timeout=120)
        assert r.returncode == 2 and "no OAK device found" in r.stderr, (r.returncode, r.stderr[-2000:])
        assert time.monotonic() - t0 < 60

    def plan(line: str) -> None:
        from litevloc.config.schema import ZenohConfig
        from litevloc.runtime.transport.bus import Bus

        robot.append(Bus(ZenohConfig(listen=(f"tcp/127.0.0.1:{robot_port}",))))  # the robot's service stands in
        p = subprocess.Popen([litevloc_exe(), *shlex.split(expand(line))[1:]], cwd=tmp_path, env=env,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        planner.append(p)
        assert p.stdout is not None
        first = p.stdout.readline()  # "planner: map ... waiting for goals" once it listens
        assert first.startswith("planner: map"), (first, p.poll())

    def goal_send(line: str) -> None:
        assert planner, "the README shows `litevloc plan` before `litevloc goal send`"
        r = _run(expand(line), tmp_path, env, timeout=120)
        p = planner[0]
        p.send_signal(signal.SIGINT)
        out, err = p.communicate(timeout=60)
        assert p.returncode == 0, err[-2000:]
        # no fused pose yet (no robot): the goal is placed on the map and waits for one
        assert r.returncode == 0 and re.search(r"goal 'goal' at node \d+", r.stdout), (r.stdout, r.stderr[-2000:])
        assert "'goals_in': 1" in out, out

    handlers: list[tuple[str, Callable[[str], None]]] = [
        (r"^litevloc demo ", demo),
        (r"^litevloc map build \$D ", prepared_by_fixture),
        (r"^litevloc convert \$D ", prepared_by_fixture),
        (r"^litevloc map build out/robot/run.mcap ", robot_map),
        (r"^litevloc map info ", map_info),
        (r"^litevloc localize ", localize),
        (r"^litevloc replay .* --frames ", replay),
        (r"^litevloc (record|run) --config oak-d ", no_camera),
        (r"^litevloc plan ", plan),
        (r"^litevloc goal send ", goal_send),
    ]
    ran = []
    try:
        for line in lines:
            handler = next((h for pattern, h in handlers if re.search(pattern, line)), None)
            assert handler is not None, f"README line without a test: {line}"
            handler(line)
            ran.append(line)
    finally:
        for p in planner:
            if p.poll() is None:
                p.kill()
        for bus in robot:
            bus.close()  # type: ignore[attr-defined]
    assert ran == lines
