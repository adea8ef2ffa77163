"""Child processes of the service (VLoc, recording reader): started one way, never left behind.

The children ignore SIGINT/SIGTERM (a terminal's Ctrl-C and systemd signal the whole process
group; the parent decides when they end) and are ended by their owner's `close()`. Where an
owner was never closed (an exception, an abandoned iterator), this module's exit handler kills
what is still running. It must run before multiprocessing's own exit handler, which sends
SIGTERM to daemonic children and then waits for them forever: `multiprocessing.util` is
imported first, so its handler is registered first and, atexit running handlers last in first
out, runs after this one.
"""

from __future__ import annotations

import atexit
import multiprocessing
import multiprocessing.util  # registers its exit handler before ours (see above)
import weakref
from collections.abc import Callable
from multiprocessing.process import BaseProcess
from typing import Any

_LIVE: weakref.WeakSet[BaseProcess] = weakref.WeakSet()


def start_child(target: Callable[..., None], args: tuple[Any, ...], name: str) -> BaseProcess:
    """Start `target(*args)` in a fresh interpreter (spawn: never a fork of a process with
    Zenoh, GTSAM and onnxruntime threads), daemonic, and remember it for the exit handler."""
    proc = multiprocessing.get_context("spawn").Process(target=target, args=args, name=name, daemon=True)
    proc.start()
    _LIVE.add(proc)
    return proc


def end_child(proc: BaseProcess, timeout_s: float) -> None:
    """Kill `proc` if it still runs and reap it (it only reads or computes: nothing to finish)."""
    if proc.pid is not None and proc.is_alive():
        proc.kill()
        proc.join(timeout_s)


@atexit.register
def _kill_children_left_running() -> None:
    for proc in list(_LIVE):
        end_child(proc, 5.0)
