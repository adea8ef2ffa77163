"""Helpers for tests that use Zenoh: free loopback ports and the probe subprocess."""

from __future__ import annotations

import json
import socket
import subprocess
import sys
import time
from pathlib import Path


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def start_probe(endpoint: str, out: Path, topics: str, counts: dict[str, int], timeout: float = 20.0,
                namespace: str = "", idle: float = 0.0, listen: bool = False,
                ros2: str = "bridge", rt_priority: int = 0) -> subprocess.Popen[str]:
    """Start `python -m litevloc.runtime.transport.probe` and wait (bounded) for its READY line.

    The probe connects to `endpoint`, or with `listen=True` listens there (the service connects)."""
    cmd = [sys.executable, "-m", "litevloc.runtime.transport.probe", "--listen" if listen else "--connect", endpoint,
           "--topics", topics,
           "--timeout", str(timeout), "--json", str(out), "--keep", "--namespace", namespace, "--ros2", ros2]
    if idle:
        cmd += ["--idle", str(idle)]
    if rt_priority:
        cmd += ["--rt-priority", str(rt_priority)]
    for k, n in counts.items():
        cmd += ["--count", f"{k}={n}"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert proc.stdout is not None
    t_end = time.monotonic() + 15.0
    line = ""
    while time.monotonic() < t_end:
        line = proc.stdout.readline().strip()
        if line or proc.poll() is not None:
            break
    if line != "READY":
        proc.kill()
        _, err = proc.communicate(timeout=5)
        raise AssertionError(f"probe did not get ready ({line!r}): {err[-2000:]}")
    return proc


def finish_probe(proc: subprocess.Popen[str], out: Path, timeout: float = 20.0) -> dict:
    try:
        _, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.communicate(timeout=5)
        raise AssertionError("probe did not finish in time") from None
    assert out.is_file(), f"probe wrote no result (rc {proc.returncode}): {err[-2000:]}"
    return dict(json.loads(out.read_text()))
